"""Generation: the executor seam, and real SUMO runs into Parquet data sets (bytes, resume, refusal, stats).

The executor: jobs in spawned worker processes (one per job if asked); failures reported by job, the rest complete.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simharness.errors import UserError
from simharness.executors import Executor, LocalExecutor, make_executor
from simharness.generation import generate
from simharness.io.parquet import Dataset
from simharness.scenario import SCENARIO_DIR, load_scenario
from simharness.stats import dataset_stats


def test_results_stream_back_for_every_job() -> None:
    pool = LocalExecutor(workers=2)
    assert isinstance(pool, Executor)
    results = {r.job: r for r in pool.map_unordered(math.sqrt, [4.0, 9.0, 16.0])}
    assert {j: r.value for j, r in results.items()} == {4.0: 2.0, 9.0: 3.0, 16.0: 4.0}
    assert all(r.ok for r in results.values())


def test_raising_and_dying_jobs_fail_alone() -> None:
    raised = {r.job: r for r in LocalExecutor(2).map_unordered(math.sqrt, [1.0, -1.0, 25.0])}
    assert raised[1.0].value == 1.0 and raised[25.0].value == 5.0
    assert not raised[-1.0].ok and raised[-1.0].error == "ValueError: math domain error"
    assert "Traceback" in raised[-1.0].traceback
    # os._exit ends the worker process without a result: that job fails, the others still run.
    died = list(LocalExecutor(1).map_unordered(os._exit, [7]))
    assert len(died) == 1 and died[0].error == "worker process died (exit code 7)"


def test_a_retried_job_is_logged(capsys) -> None:
    died = list(LocalExecutor(1, max_retries=1).map_unordered(os._exit, [7]))
    assert died[0].attempts == 2 and not died[0].ok
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["simharness: job 7: attempt 1 of 2 ended (worker process died (exit code 7)); retrying in a "
                   "fresh process"]


def test_each_job_gets_a_fresh_process() -> None:  # when asked: workers are reused by default (test_executors)
    pids = [r.value for r in LocalExecutor(2, jobs_per_worker=1).map_unordered(_pid, range(3))]
    assert len(set(pids)) == 3 and os.getpid() not in pids


def _pid(_: int) -> int:
    return os.getpid()


def test_make_executor_names() -> None:
    assert make_executor("local", 3).workers == 3
    with pytest.raises(UserError, match="only used with --executor ray"):
        make_executor("local", 2, address="auto")
    with pytest.raises(UserError, match="unknown executor"):
        make_executor("dask", 2)
    with pytest.raises(UserError, match="positive"):
        make_executor("local", 0)


# ---------------------------------------------------------------------- generation with real SUMO
DURATION = 20.0  # recorded seconds per scene: short; the scenario's own warm-up fills the road first


def short_scenario(folder: Path, duration: float = DURATION) -> Path:
    """The shipped dense arterial with a short recording, as a file (the CLI takes files)."""
    text = (SCENARIO_DIR / "sumo_arterial_dense.toml").read_text()
    text = re.sub(r"(?m)^duration\s*=.*$", f"duration = {duration}", text)
    path = folder / "dense_short.toml"
    path.write_text(text)
    return path


def run_cli(*argv: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simharness", *argv], capture_output=True, text=True, **kw)


def shard_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.name not in ("_runs.jsonl", "_lock")}


@pytest.fixture(scope="module")
def dense(tmp_path_factory) -> tuple[Path, Path]:
    """(scenario file, data set of seeds 0 and 1 generated with 2 workers)."""
    folder = tmp_path_factory.mktemp("dense")
    scenario = short_scenario(folder)
    out = folder / "ds"
    summary = generate(load_scenario(scenario), [0, 1], out, workers=2, progress=False)
    assert summary["done"] == 2 and not summary["failed"], summary
    return scenario, out


def test_generated_data_set_reads_back(dense) -> None:
    scenario, out = dense
    ds = Dataset(out)
    assert ds.scene_ids == ["scene-000000", "scene-000001"]
    spec = load_scenario(scenario)
    scene = ds.scene(0)
    assert scene.num_frames == spec.num_frames and scene.dt == pytest.approx(spec.dt)
    assert scene.meta["seed"] == 0 and scene.meta["config_hash"] == spec.config_hash()
    assert ds.road is not None and ds.manifest["info"]["seeds"] == [0, 1]
    assert ds.manifest["rows"] == sum(int(s.valid.sum()) for s in ds)
    log = [json.loads(line) for line in (out / "_runs.jsonl").read_text().splitlines()]
    assert log[-1]["config_hash"] == spec.config_hash() and log[-1]["seeds"] == [0, 1]


def test_same_seed_same_bytes_other_seed_not(dense, tmp_path: Path) -> None:
    scenario, out = dense
    again = tmp_path / "again"
    generate(load_scenario(scenario), [0], again, workers=1, progress=False)
    a, b = shard_bytes(out), shard_bytes(again)
    assert b["scene-000000.parquet"] == a["scene-000000.parquet"]
    assert a["scene-000000.parquet"] != a["scene-000001.parquet"]


def test_dense_scenario_meets_its_targets(dense) -> None:
    s = dataset_stats(dense[1])
    assert s["agents_within_50m"] >= 15, s["agents_within_50m"]
    assert s["density_per_km"] >= 100, s["density_per_km"]
    assert s["distinct_types_per_frame"]["min"] >= 5, s["distinct_types_per_frame"]
    assert sum(s["agents_per_frame_by_type"].values()) == pytest.approx(s["agents_per_frame"], rel=1e-3)


def test_killed_generation_resumes_to_the_same_data_set(dense, tmp_path: Path) -> None:
    scenario, reference = dense
    out = tmp_path / "resumed"
    cmd = [sys.executable, "-m", "simharness", "generate", str(scenario), "--seeds", "0-1", "--out", str(out),
           "--workers", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not (out / "scene-000000.parquet").exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, "generation ended before it could be interrupted"
        os.killpg(proc.pid, signal.SIGKILL)  # the command and its worker, mid-way through seed 1
    finally:
        proc.wait()
    assert not (out / "scene-000001.parquet").exists()
    done = run_cli(*cmd[3:])
    assert done.returncode == 0, done.stderr
    assert "1 scenes generated, 1 already complete" in done.stdout
    assert shard_bytes(out) == shard_bytes(reference)  # no duplicate, none lost, no temp file, same manifest
    assert run_cli(*cmd[3:]).stdout.count("0 scenes generated, 2 already complete") == 1


def test_mixing_another_config_is_refused(dense, tmp_path: Path) -> None:
    scenario, out = dense
    before = shard_bytes(out)
    proc = run_cli("generate", str(scenario), "--seeds", "2", "--out", str(out), "--duration", "3")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "refusing to mix" in lines[0] and str(out) in lines[0]
    assert shard_bytes(out) == before
    (tmp_path / "notes.txt").write_text("mine")
    proc = run_cli("generate", str(scenario), "--seeds", "0", "--out", str(tmp_path))
    assert proc.returncode == 2 and "notes.txt" in proc.stderr and proc.stderr.count("\n") == 1


def test_stats_command_json_and_figure(dense, tmp_path: Path) -> None:
    out = dense[1]
    proc = run_cli("stats", str(out), "--json", "--figure", str(tmp_path / "frame.png"))
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    for key in ("frames", "agents_per_frame", "agents_per_frame_by_type", "distinct_types", "agents_within_50m",
                "density_per_km", "collisions", "teleports"):
        assert key in s
    assert s["frames"] == 2 * int(DURATION * 5) and s["distinct_types"] >= 5
    assert {"simulator", "box_overlap", "rate_per_1000_agent_min"} <= set(s["collisions"])
    png = (tmp_path / "frame.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    table = run_cli("stats", str(out))
    assert table.returncode == 0 and "Density/km" in table.stdout and "teleports:" in table.stdout
