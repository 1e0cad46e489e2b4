"""Trajectory predictors: TraPHic (models/traphic.py), constant velocity and the paper's baselines.

features.py builds windows and TraPHic's inputs, models/ holds one file per model (registry in
models/__init__.py), losses.py the NLL and MSE, train.py the training loop, predict.py the
`Predictor` wrapper, weights/ the shipped checkpoint. Imports `simharness.scene` and
`simharness.errors` only (train.py also reads data sets through `simharness.io.parquet`).
"""
