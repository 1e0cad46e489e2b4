"""Open-loop evaluation: protocol windows, any predictor, and `simharness evaluate` end to end on SUMO data."""

import json
import subprocess
import sys

import numpy as np
import pytest
from _predictor_data import flow_scene

from predictor.models.const_vel import ConstantVelocity
from simharness.evaluation import evaluate
from simharness.io.parquet import write_dataset
from simharness.protocols import PROTOCOLS, history_and_truth, windows
from simharness.scene import AgentType, Scene


def _straight(seed: int) -> Scene:
    """Agents at constant velocity: constant velocity must be exact."""
    rng = np.random.default_rng(seed)
    n, t = 6, 60
    v = rng.uniform(-3, 3, (n, 1, 2))
    xy = rng.uniform(0, 50, (n, 1, 2)) + v * (np.arange(t) * 0.2)[None, :, None]
    valid = np.ones((n, t), bool)
    valid[0, 30] = False  # a gap: agent 0 is never a target of a window that spans frame 30
    return Scene(xy=xy, heading=np.zeros((n, t)), speed=np.zeros((n, t)), valid=valid,
                 agent_id=[f"p{i}" for i in range(n)], agent_type=[AgentType.PEDESTRIAN] * n,
                 length=np.full(n, 0.5), width=np.full(n, 0.5), dt=0.2)


def test_windows_select_full_window_targets():
    scene, proto = _straight(0), PROTOCOLS["traphic"]
    wins = list(windows(scene, proto))
    assert wins and all(now >= 14 and now + 25 < scene.num_frames for now, _ in wins)
    for now, rows in wins:
        spans_gap = now - 14 <= 30 <= now + 25
        assert (0 in rows) == (not spans_gap)
    hist, truth, tvalid = history_and_truth(scene, wins[0][0], proto)
    assert hist.num_frames == 15 and truth.shape == (6, 25, 2) and tvalid[1:].all()


def test_const_vel_is_exact_on_constant_velocity(tmp_path):
    data = tmp_path / "straight"
    write_dataset([_straight(s) for s in range(3)], data, {"source": "test"})
    res = evaluate(data, ConstantVelocity(), "traphic", split="all", progress=False, name="cv")
    assert res["ade"] == pytest.approx(0.0, abs=1e-4) and res["fde_rmse"] == pytest.approx(0.0, abs=1e-4)
    assert res["nll"] is None and res["by_type"]["pedestrian"]["samples"] == res["samples"] > 0


def test_evaluate_cli_end_to_end_on_generated_sumo_data(tmp_path):
    data, out = tmp_path / "arterial", tmp_path / "eval"
    gen = subprocess.run([sys.executable, "-m", "simharness", "generate", "sumo_arterial_dense", "--seeds", "0-2",
                          "--out", str(data), "--duration", "20"], capture_output=True, text=True)
    assert gen.returncode == 0, gen.stderr[-500:]
    proc = subprocess.run([sys.executable, "-m", "simharness", "evaluate", "--data", str(data), "--model",
                           "const-vel", "--out", str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-500:]
    m = json.loads((out / "metrics.json").read_text())
    for key in ("ade", "fde", "ade_rmse", "fde_rmse", "rmse_per_second", "nll", "samples", "by_type", "by_density"):
        assert key in m
    assert len(m["rmse_per_second"]) == 5 and m["samples"] > 0 and m["split"] == "test" and m["scenes"] == 1
    assert 0 < m["ade"] < m["fde"] and m["ade"] <= m["ade_rmse"]
    assert sum(v["samples"] for v in m["by_type"].values()) == m["samples"]
    assert all({"ade", "fde", "samples"} <= set(v) for v in m["by_type"].values())
    assert (out / "rmse_curve.png").stat().st_size > 0 and (out / "forecasts.png").stat().st_size > 0
    assert "ADE" in proc.stdout


def test_model_predictor_scored_by_the_same_code(tmp_path):
    import torch

    from predictor.features import WindowConfig
    from predictor.models import build_model
    from predictor.predict import ModelPredictor

    torch.manual_seed(0)
    data = tmp_path / "flow"
    write_dataset([flow_scene(s) for s in range(3)], data, {"source": "test"})
    pred = ModelPredictor(build_model("traphic", {"history": 15, "future": 25}).eval(), WindowConfig())
    res = evaluate(data, pred, "traphic", split="all", progress=False, figure_dir=tmp_path / "fig", name="t")
    assert res["nll"] is not None and np.isfinite(res["nll"]) and res["samples"] > 0
    assert (tmp_path / "fig" / "forecasts.png").is_file()


def test_registry_names_and_run_folders(tmp_path):
    from simharness.errors import UserError
    from simharness.predictors import PREDICTORS, load_predictor
    from simharness.scene import Predictor

    assert {"const-vel", "traphic"} <= set(PREDICTORS)
    for name in ("const-vel", "traphic"):
        p = load_predictor(name)
        assert isinstance(p, Predictor)
        scene = flow_scene(4, n=8, t=15)
        fc = p.predict(scene, np.arange(8), 10)
        assert fc.mean.shape == (8, 10, 2) and np.isfinite(fc.mean).all()
    with pytest.raises(UserError, match="unknown predictor 'nope'"):
        load_predictor("nope")
    # const-vel:N extrapolates the mean displacement over the last N steps: on a track whose every other position
    # jumps 0.4 m sideways, N = 2 (an even span) keeps the steady 1 m a step that the last step (N = 1) misreads
    t = np.arange(15, dtype=np.float32)
    scene = flow_scene(4, n=1, t=15)
    scene = scene.replace(xy=np.stack([t, 0.4 * (t % 2)], -1)[None], valid=np.ones((1, 15), bool))
    last, smooth = (load_predictor(n).predict(scene, np.array([0]), 3) for n in ("const-vel", "const-vel:2"))
    assert smooth.mean[0, :, 1] == pytest.approx([0.0] * 3) and last.mean[0, 0, 1] == pytest.approx(-0.4)
    assert smooth.mean[0, :, 0] == pytest.approx(14 + np.arange(1, 4))
    assert load_predictor("const-vel:2").name == "const-vel:2" and load_predictor("const-vel").name == "const-vel"
    for bad in ("const-vel:0", "const-vel:x", "const-vel:"):
        with pytest.raises(UserError, match="const-vel:N"):
            load_predictor(bad)
    with pytest.raises(UserError, match="config.json"):
        load_predictor(tmp_path)  # a folder that is not a run


def test_evaluate_scores_the_test_scenes_a_run_recorded(tmp_path, capsys):
    """`evaluate --model RUN` without --test-scenes scores the scenes the run held out (config.json), also when it
    was trained with --test-scenes; on another data set, the hash split."""
    from _predictor_data import write_flow_dataset

    from predictor.split import split_scenes
    from predictor.train import train
    from simharness.cli import main

    data = write_flow_dataset(tmp_path / "flow", scenes=4)
    ids = [f"scene-{i:06d}" for i in range(4)]
    named = next(s for s in ids if s not in split_scenes(ids)["test"])  # not the hash split's test scene
    train(data, "rnn-ed", tmp_path / "run", epochs=1, warmup_epochs=1, batch_size=64, max_samples=64, threads=1,
          progress=False, test_scenes=[named], cache_dir=tmp_path / "cache")
    capsys.readouterr()
    assert main(["evaluate", "--data", str(data), "--model", str(tmp_path / "run"), "--out", str(tmp_path / "ev")]) == 0
    out = capsys.readouterr().out
    assert json.loads((tmp_path / "ev" / "metrics.json").read_text())["scene_ids"] == [named]
    assert "scoring split 'test': 1 of 4 scenes (the ones the model's training held out, as its run config" in out
    other = write_flow_dataset(tmp_path / "other", scenes=5)  # another content hash: the hash split
    run = str(tmp_path / "run")
    assert main(["evaluate", "--data", str(other), "--model", run, "--out", str(tmp_path / "ev2")]) == 0
    assert "by a hash of the scene ids" in capsys.readouterr().out
    assert json.loads((tmp_path / "ev2" / "metrics.json").read_text())["scene_ids"] == split_scenes(
        [f"scene-{i:06d}" for i in range(5)])["test"]
