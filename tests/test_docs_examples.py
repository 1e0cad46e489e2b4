"""The docs' examples run: docs/api.md's Python blocks, and docs/predictors.md's two plug-ins (examples/) through
`simharness evaluate` and `simharness stress` (real highway backend, real torch, real worker processes; the runs
through the command line and the suite are `-m slow`: a minute or more each on 2 cores).

Each runs in a temporary folder holding a copy of examples/, so nothing is written into the repository."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    r = subprocess.run(args, capture_output=True, text=True, cwd=cwd, env=ENV, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


def simharness(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return run([sys.executable, "-m", "simharness", *args], cwd)


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A folder with a copy of examples/ and a small data set (one 12 s scene of the dense highway mix)."""
    work = tmp_path_factory.mktemp("docs")
    shutil.copytree(REPO / "examples", work / "examples", ignore=shutil.ignore_patterns("*.pt", "__pycache__"))
    simharness("generate", "highway_mixed_dense", "--seeds", "0", "--duration", "12", "--out", "data", "--workers",
               "1", cwd=work)
    return work


def python_blocks(doc: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", doc.read_text(), re.S)


@pytest.mark.parametrize("block", [0, 1, pytest.param(2, marks=pytest.mark.slow)])  # 2: the suite, worker processes
def test_api_page_runs(work, block):
    """Each Python block of docs/api.md is a script that runs as written and prints its figures."""
    blocks = python_blocks(REPO / "docs" / "api.md")
    assert len(blocks) == 3
    script = work / f"api_block_{block}.py"
    script.write_text(blocks[block])
    out = run([sys.executable, str(script)], work).stdout
    expected = [r"examples/const_accel.py:ConstAccel: ADE \d+\.\d+ m", r"collision rate \d\.\d\d, composite",
                r"# Stress suite leaderboard"][block]
    assert re.search(expected, out), out


def metrics(work: Path, model: str, out: str) -> dict:
    simharness("evaluate", "--data", "data", "--split", "all", "--model", model, "--out", out, cwd=work)
    return json.loads((work / out / "metrics.json").read_text())


@pytest.mark.slow
def test_const_accel_example(work):
    """Open loop it beats constant velocity at 1 s on the dense mix (speed changes are real there); the stress
    suite runs it beside constant velocity, paired on the seeds."""
    mine = metrics(work, "examples/const_accel.py:ConstAccel", "ev-ca")
    cv = metrics(work, "const-vel", "ev-cv")
    assert mine["samples"] == cv["samples"] > 0
    assert mine["rmse_per_second"][0] < cv["rmse_per_second"][0]
    simharness("stress", "--predictor", "examples/const_accel.py:ConstAccel,const-vel", "--scenarios", "cut_in",
               "--seeds", "0", "--duration", "5", "--workers", "1", "--out", "stress-ca", cwd=work)
    board = json.loads((work / "stress-ca" / "leaderboard.json").read_text())
    assert board["pooled"]["examples/const_accel.py:ConstAccel"]["episodes"] == 1


@pytest.mark.slow
def test_tiny_torch_example(work):
    """Without weights: one line saying how to train it, exit 2. Trained by its own entry point, it scores with an
    NLL (its learned sigma) and runs through the stress suite."""
    r = subprocess.run([sys.executable, "-m", "simharness", "evaluate", "--data", "data", "--split", "all", "--model",
                        "examples/tiny_torch.py:TinyTorch", "--out", "ev-none"], capture_output=True, text=True,
                       cwd=work, env=ENV, timeout=300)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "train them first" in r.stderr
    run([sys.executable, "examples/tiny_torch.py", "--data", "data", "--epochs", "100"], work)
    assert (work / "examples" / "tiny_torch.pt").is_file()
    m = metrics(work, "examples/tiny_torch.py:TinyTorch", "ev-tt")
    assert m["samples"] > 0 and m["nll"] is not None and m["ade"] < 10
    simharness("stress", "--predictor", "examples/tiny_torch.py:TinyTorch", "--scenarios", "cut_in", "--seeds", "0",
               "--duration", "5", "--workers", "1", "--out", "stress-tt", cwd=work)
    board = json.loads((work / "stress-tt" / "leaderboard.json").read_text())
    assert board["pooled"]["examples/tiny_torch.py:TinyTorch"]["episodes"] == 1


def test_tiny_torch_untrained_is_constant_velocity(work):
    import runpy

    import numpy as np

    from simharness.io.parquet import Dataset
    from simharness.plugins import load_predictor
    from simharness.protocols import get_protocol, history_and_truth, windows

    ds = Dataset(work / "data")
    scene = ds.scene(ds.scene_ids[0])
    now, rows = next(windows(scene, get_protocol("traphic")))
    hist, _, _ = history_and_truth(scene, now, get_protocol("traphic"))
    untrained = runpy.run_path(str(work / "examples" / "tiny_torch.py"))["TinyTorch"](weights=None)
    a = untrained.predict(hist, rows, 25)
    b = load_predictor("const-vel").predict(hist, rows, 25)
    assert np.abs(a.mean - b.mean).max() < 1e-3 and a.sigma_rho.shape == (len(rows), 25, 3)
