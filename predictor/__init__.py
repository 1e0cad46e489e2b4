"""Trajectory predictors: TraPHic (models/traphic.py), constant velocity and the paper's baselines.

features.py builds windows and TraPHic's inputs, windows_cache.py keeps them on disk (compact, outside
the data set), models/ holds one file per model (registry in models/__init__.py; models/lstm.py the
decoder's constant-input LSTM), losses.py the NLL and MSE, train.py the training loop, predict.py the
`Predictor` wrapper, weights/ the shipped checkpoint. Imports `simharness.scene` and
`simharness.errors` only (train.py also reads data sets through `simharness.io.parquet`).
"""
