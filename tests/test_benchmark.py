"""`simharness benchmark`: every method trained and scored on a real (tiny) SUMO data set, tables written.

The data set is the shipped dense arterial scenario recorded for 12 s over 3 seeds (one scene per split).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from simharness.benchmark import BASELINES, METHODS, PROFILES, REFERENCE, VARIANTS, benchmark, verdict
from simharness.errors import UserError
from simharness.generation import generate
from simharness.scenario import SCENARIO_DIR, load_scenario


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("bench")
    text = (SCENARIO_DIR / "sumo_arterial_dense.toml").read_text()
    scenario = folder / "dense_short.toml"
    scenario.write_text(re.sub(r"(?m)^duration\s*=.*$", "duration = 12.0", text))
    out = folder / "ds"
    summary = generate(load_scenario(scenario), [0, 1, 2], out, workers=2, progress=False)
    assert summary["done"] == 3 and not summary["failed"], summary
    return out


@pytest.fixture(scope="module")
def quick_run(tiny: Path, tmp_path_factory) -> Path:
    """The CLI end to end, as a user runs it (one worker: every method in this one process)."""
    out = tmp_path_factory.mktemp("quick")
    proc = subprocess.run([sys.executable, "-m", "simharness", "benchmark", "--data", str(tiny), "--profile", "quick",
                           "--out", str(out), "--workers", "1"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "| TraPHic |" in proc.stdout and "| S-GAN |" in proc.stdout
    return out


def test_quick_benchmark_writes_every_table(quick_run: Path, tiny: Path) -> None:
    res = json.loads((quick_run / "results.json").read_text())
    assert list(res["methods"]) == [*METHODS, REFERENCE] and not res["failed"]
    assert res["profile"] == PROFILES["quick"].to_dict() and res["data_hash"]
    for name, row in res["methods"].items():
        m = row["metrics"]
        assert m["samples"] > 0 and m["split"] == "test"
        assert 0 < m["ade"] <= m["ade_rmse"] and 0 < m["fde"] <= m["fde_rmse"]  # mean <= root mean square
        assert len(m["rmse_per_second"]) == 5
        if name != REFERENCE:
            assert row["train_s"] > 0 and row["params"] > 0 and row["train_samples"] == PROFILES["quick"].max_samples
            assert (quick_run / "runs" / name / "model.pt").is_file()
            cfg = json.loads((quick_run / "runs" / name / "config.json").read_text())
            assert cfg["model"] == name and cfg["model_config"]["residual"] is True  # the default form
    # Every method was scored on the same test windows.
    assert len({r["metrics"]["samples"] for r in res["methods"].values()}) == 1
    gan = res["methods"]["social-gan"]["metrics"]
    assert gan["nll"] is None and gan["min_ade"] <= gan["ade"] and gan["min_fde"] <= gan["fde"]
    assert all(res["methods"][m]["metrics"]["nll"] is not None for m in ("rnn-ed", "traphic", "cs-lstm"))
    assert res["stats"]["scenes"] == 3 and res["stats"]["distinct_types"] >= 5
    assert set(res["verdict"]) >= {"ade_rmse", "fde_rmse", "beats_every_baseline"}
    md = (quick_run / "results.md").read_text()
    assert "Protocol `traphic`" in md and "residual over constant velocity" in md
    for heading in ("(the paper's Table 1)", "## Methods", "## Ablation", "## RMSE per horizon second",
                    "Best of 20 samples"):
        assert heading in md
    for label in ("RNN-ED", "S-LSTM", "S-GAN", "CS-LSTM", "TraPHic-B", "TraPHic-He", "TraPHic-Ho", "Const-vel"):
        assert f"| {label} |" in md
    for fig in ("rmse_curve.png", "methods.png"):
        assert (quick_run / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(quick_run.glob(".*tmp*"))  # nothing half-written left behind


def test_no_residual_trains_the_papers_form(tiny: Path, tmp_path: Path) -> None:
    import dataclasses

    res = benchmark(tiny, dataclasses.replace(PROFILES["quick"], residual=False), tmp_path, workers=1,
                    methods=("rnn-ed",), progress=False)
    assert res["profile"]["residual"] is False and "direct means" in (tmp_path / "results.md").read_text()
    assert json.loads((tmp_path / "runs" / "rnn-ed" / "config.json").read_text())["model_config"]["residual"] is False


def test_same_seed_same_scores_in_worker_processes(quick_run: Path, tiny: Path, tmp_path: Path) -> None:
    again = benchmark(tiny, "quick", tmp_path, workers=2, methods=("cs-lstm",), progress=False)
    first = json.loads((quick_run / "results.json").read_text())["methods"]["cs-lstm"]["metrics"]
    assert again["methods"]["cs-lstm"]["metrics"]["ade_rmse"] == first["ade_rmse"]
    assert again["methods"]["cs-lstm"]["metrics"]["rmse_per_second"] == first["rmse_per_second"]


def test_verdict_compares_traphic_with_the_best_baseline() -> None:
    def row(ade: float, fde: float) -> dict:
        return {"metrics": {"ade_rmse": ade, "fde_rmse": fde}}

    rows = {"rnn-ed": row(3.0, 5.0), "cs-lstm": row(2.0, 4.0), "social-gan": row(2.5, 3.5), "traphic": row(1.5, 3.7)}
    v = verdict(rows)
    assert v["ade_rmse"]["best_baseline"] == "cs-lstm" and v["ade_rmse"]["relative_change"] == pytest.approx(-0.25)
    assert v["fde_rmse"]["best_baseline"] == "social-gan" and not v["beats_every_baseline"]
    assert v["vs_cs_lstm_ade_rmse"] == pytest.approx(-0.25)
    assert set(BASELINES) | set(VARIANTS) == set(METHODS)


def test_bad_input_is_one_line(tiny: Path, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="unknown benchmark profile"):
        benchmark(tiny, "huge", tmp_path)
    with pytest.raises(UserError, match="unknown methods"):
        benchmark(tiny, "quick", tmp_path, methods=("lstm-9000",))
    proc = subprocess.run([sys.executable, "-m", "simharness", "benchmark", "--data", str(tmp_path / "nowhere"),
                           "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "simharness: error:" in proc.stderr
