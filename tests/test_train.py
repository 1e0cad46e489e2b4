"""Training on a small real Parquet data set: loss falls, checkpoints round-trip, bad ones fail clearly."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from _predictor_data import flow_scene, write_flow_dataset

from predictor.checkpoint import load_checkpoint
from predictor.features import WindowConfig
from predictor.predict import ModelPredictor
from predictor.split import split_scenes
from predictor.train import load_windows, train
from simharness.errors import UserError


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    data = write_flow_dataset(tmp_path_factory.mktemp("flow") / "data")
    out = tmp_path_factory.mktemp("run") / "traphic-b"
    res = train(data, "traphic-b", out, epochs=3, warmup_epochs=3, batch_size=64, max_samples=600, seed=0,
                threads=1, progress=False)
    return data, out, res


def test_short_training_lowers_validation_loss(run):
    _, out, res = run
    hist = res["val_history"]
    assert hist[0]["loss"] == "init" and len(hist) == 4
    assert hist[-1]["mse"] < 0.5 * hist[0]["mse"]
    assert (out / "model.pt").is_file() and (out / "log.csv").read_text().count("\n") == 4
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["model"] == "traphic-b" and cfg["seed"] == 0 and len(cfg["data_hash"]) == 64
    assert {"torch", "numpy", "python"} <= set(cfg["versions"])


def test_split_is_by_scene_and_shared(run):
    data, out, _ = run
    cfg = json.loads((out / "config.json").read_text())
    split = split_scenes(sum(cfg["split"].values(), []))
    assert split == cfg["split"]
    assert not set(split["train"]) & set(split["test"]) and not set(split["val"]) & set(split["test"])
    store = load_windows(data, WindowConfig(), progress=False)
    test_idx = store.samples_of(split["test"])
    scene_of = np.asarray(store.scene_ids)[store.a["sample_scene"][test_idx]]
    assert set(scene_of) == set(split["test"])
    with pytest.raises(UserError, match="at least 3 scenes"):
        split_scenes(["a", "b"])


def test_checkpoint_round_trip(run):
    _, out, _ = run
    a = ModelPredictor.from_run(out)
    b, _ = load_checkpoint(out / "model.pt", out / "config.json")
    scene = flow_scene(9, n=10, t=16)
    fa = a.predict(scene, np.arange(10), 25)
    fb = ModelPredictor(b, a.window).predict(scene, np.arange(10), 25)
    np.testing.assert_array_equal(fa.mean, fb.mean)
    state = torch.load(out / "model.pt", weights_only=True)
    assert all(torch.equal(v, a.model.state_dict()[k]) for k, v in state.items())


def test_bad_checkpoints_fail_with_one_clear_line(run, tmp_path):
    _, out, _ = run
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "config.json").write_text((out / "config.json").read_text())
    (bad / "model.pt").write_bytes(b"not a checkpoint at all")
    with pytest.raises(UserError, match="corrupt or not a torch checkpoint"):
        ModelPredictor.from_run(bad)
    other = tmp_path / "other"
    other.mkdir()
    cfg = json.loads((out / "config.json").read_text())
    cfg["model"] = "traphic"  # traphic-b weights under a full TraPHic config
    (other / "config.json").write_text(json.dumps(cfg))
    (other / "model.pt").write_bytes((out / "model.pt").read_bytes())
    with pytest.raises(UserError, match="does not fit model 'traphic'"):
        ModelPredictor.from_run(other)
    proc = subprocess.run([sys.executable, "-m", "simharness", "evaluate", "--data", str(run[0]), "--model",
                           str(bad)], capture_output=True, text=True)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "corrupt" in lines[0]


def test_windows_cache_lives_outside_the_data_set(run, tmp_path, monkeypatch):
    data = run[0]  # already trained on: its windows were cached somewhere
    assert all(p.name.startswith("_") or p.suffix == ".parquet" for p in data.iterdir())
    monkeypatch.setenv("SIMHARNESS_CACHE_DIR", str(tmp_path))
    store = load_windows(data, WindowConfig(stride=3), progress=False)
    assert len(store) > 0 and len(list((tmp_path / "windows").glob("windows-*.npz"))) == 1
    assert all(p.name.startswith("_") or p.suffix == ".parquet" for p in data.iterdir())
