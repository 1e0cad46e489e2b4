"""Converging training: the learning-rate schedules, early stopping that keeps the best epoch's weights, and the
device choice. Only the CPU is exercised here (no GPU on the machines the suite runs on); `--device auto`
picking CUDA is checked only as far as torch reports a GPU."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from _predictor_data import write_flow_dataset

from predictor.checkpoint import load_checkpoint
from predictor.features import WindowConfig
from predictor.split import split_scenes
from predictor.train import LR_FLOOR, _epoch_eval, load_windows, lr_factor, resolve_device, train
from simharness.errors import UserError


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_flow_dataset(tmp_path_factory.mktemp("flow") / "data", scenes=4)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")  # one windows cache for the module's runs


def test_cosine_warms_up_then_decays_to_the_floor() -> None:
    f = [lr_factor(k, 100, 5) for k in range(100)]
    assert f[0] == pytest.approx(0.2) and f[4] == pytest.approx(1.0)
    assert all(a >= b for a, b in zip(f[4:], f[5:], strict=False))  # never rises after the warm-up
    assert f[-1] == pytest.approx(LR_FLOOR, abs=1e-3) and f[50] == pytest.approx((1 + LR_FLOOR) / 2, abs=0.05)


def _log(out) -> list[dict[str, str]]:
    with open(out / "log.csv") as fh:
        return list(csv.DictReader(fh))


def test_cosine_schedule_lowers_the_rate_each_epoch(data, cache, tmp_path) -> None:
    res = train(data, "traphic-b", tmp_path / "run", epochs=3, warmup_epochs=1, batch_size=64, max_samples=256,
                threads=1, progress=False, lr=2e-3, cache_dir=cache)
    lrs = [float(r["lr"]) for r in _log(tmp_path / "run")]
    # 12 steps: a one-step warm-up, then the rate at each epoch's start falls towards the floor.
    assert len(lrs) == 3 and lrs[0] == pytest.approx(2e-3) and lrs[0] > lrs[1] > lrs[2] > LR_FLOOR * 2e-3
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["train"]["lr_schedule"] == "cosine" and cfg["device"] == "cpu" and res["epochs_run"] == 3


def test_early_stopping_keeps_the_best_epochs_weights(data, cache, tmp_path) -> None:
    """A learning rate far too high makes validation worse after the first epochs: training stops after `patience`
    epochs without progress, and model.pt scores exactly the best validation value."""
    out = tmp_path / "run"
    res = train(data, "rnn-ed", out, epochs=12, warmup_epochs=0, batch_size=32, max_samples=256, threads=1,
                progress=False, lr=0.3, lr_schedule="constant", patience=2, cache_dir=cache, seed=1)
    assert res["epochs_run"] < 12 and res["epochs_run"] == res["best_epoch"] + 2
    model, cfg = load_checkpoint(out / "model.pt", out / "config.json")
    store = load_windows(data, WindowConfig(), progress=False, cache_dir=cache)
    val = _epoch_eval(model, store, store.samples_of(split_scenes(cfg["split"]["train"] + cfg["split"]["val"]
                                                                  + cfg["split"]["test"])["val"]),
                      32, torch.device("cpu"))
    assert val["nll"] == pytest.approx(res["best_val"], rel=1e-5)
    assert len(_log(out)) == res["epochs_run"] and cfg["epochs_run"] == res["epochs_run"]


def test_patience_counts_epochs_after_the_warm_up_only(data, cache, tmp_path) -> None:
    """A learning rate far too high: every epoch is worse than the start, yet training runs through the warm-up and
    `patience` epochs of the NLL phase after its best before it stops; only the NLL phase's epochs (their sigma is
    fitted) are candidates, and log.csv's val_ade is the criterion that picked the checkpoint."""
    out = tmp_path / "run"
    res = train(data, "rnn-ed", out, epochs=12, warmup_epochs=2, batch_size=32, max_samples=256, threads=1,
                progress=False, lr=0.3, lr_schedule="constant", patience=2, cache_dir=cache, seed=1, select="ade")
    ades = [res["val_history"][0]["ade"]] + [float(r["val_ade"]) for r in _log(out)]
    assert min(ades[1:]) > ades[0]  # too high a rate: no epoch beats the fresh start, which is no candidate
    assert res["best_epoch"] == 3 + int(np.argmin(ades[3:]))
    assert res["best_val"] == pytest.approx(min(ades[3:]), rel=1e-3)
    assert res["epochs_run"] == res["best_epoch"] + 2  # stopped `patience` NLL epochs after the best, not fewer


def test_plateau_schedule_halves_when_validation_stalls(data, cache, tmp_path) -> None:
    train(data, "rnn-ed", tmp_path / "run", epochs=10, warmup_epochs=0, batch_size=32, max_samples=256, threads=1,
          progress=False, lr=0.3, lr_schedule="plateau", cache_dir=cache, seed=1)
    log = _log(tmp_path / "run")
    lrs, nll = np.array([float(r["lr"]) for r in log]), np.array([float(r["val_nll"]) for r in log])
    stalled = nll[1:] >= np.minimum.accumulate(nll)[:-1]  # epoch k + 1 no better than the best before it
    assert lrs[0] == pytest.approx(0.3) and stalled[:-1].any()
    # The rate at the start of an epoch is halved exactly after each stalled epoch, and kept otherwise.
    np.testing.assert_allclose(lrs[2:] / lrs[1:-1], np.where(stalled[:-1], 0.5, 1.0), rtol=0.01)  # log: 3 digits


def test_device_choice() -> None:
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu").type == "cpu"
    if not torch.cuda.is_available():
        with pytest.raises(UserError, match="no CUDA GPU"):
            resolve_device("cuda")
    with pytest.raises(UserError, match="unknown device"):
        resolve_device("tpu")


def test_bad_settings_are_one_line(data, tmp_path) -> None:
    proc = subprocess.run([sys.executable, "-m", "simharness", "train", "--data", str(data), "--out",
                           str(tmp_path / "r"), "--epochs", "1", "--patience", "0"], capture_output=True, text=True)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "patience 0" in proc.stderr
    assert not (tmp_path / "r" / "model.pt").exists()
    with pytest.raises(UserError, match="unknown learning-rate schedule 'linear'"):
        train(data, "rnn-ed", tmp_path / "r", lr_schedule="linear", progress=False)
