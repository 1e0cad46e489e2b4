"""The closed loop on the real backends: blind vs oracle into a queue, determinism, scores, the CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simharness.closedloop import (
    EpisodeJob,
    LoopConfig,
    aggregate,
    bootstrap_ci,
    prepare_spec,
    run_closed_loop,
    run_episode,
    score_episode,
)
from simharness.io.parquet import Dataset
from simharness.scenario import load_scenario
from simharness.scene import AgentType, Scene

# A slow, dense queue on a lane-less SUMO arterial; the ego enters at 8 m/s behind it. With
# reaction "ignore" the background never reacts to the ego.
QUEUE = """
name = "queue_ahead"
backend = "sumo"
duration = 10.0
warmup = 60.0
[road]
length = 300.0
speed_limit = 2.0
[demand]
car = 1500
motorcycle = 800
bus = 100
[ego]
enabled = true
insert_at = 1.0
speed = 8.0
reaction = "ignore"
"""

SHORT_HIGHWAY = {"duration": 12.0, "warmup": 10.0, "ego.insert_at": 3.0}


@pytest.fixture(scope="module")
def queue_results(tmp_path_factory):
    path = tmp_path_factory.mktemp("queue") / "queue_ahead.toml"
    path.write_text(QUEUE)
    spec = load_scenario(path)
    # Seeds where the ego enters with room to stop (on seed 0 it enters against a car, at that car's speed).
    return {name: run_closed_loop(spec, name, [1, 2], workers=2, progress=False) for name in ("blind", "oracle")}


def test_blind_ego_runs_into_the_queue_and_the_oracle_does_not(queue_results):
    for r in queue_results["blind"]:
        s = r["scores"]
        assert s["ego_present"] and s["collided"] == 1.0 and s["at_fault_collided"] == 1.0
    for r in queue_results["oracle"]:
        s = r["scores"]
        # Rear-enders by the (ignoring) background may still touch it; it never runs into anyone itself.
        assert s["ego_present"] and s["at_fault_collided"] == 0.0, s
        assert s["mean_speed"] < 4.0  # it slowed down for the queue


def test_oracle_is_exact_when_the_background_ignores_the_ego(queue_results):
    for r in queue_results["oracle"]:
        assert r["scores"]["online_samples"] > 0
        assert r["scores"]["online_ade"] == pytest.approx(0.0, abs=1e-4)


def test_episode_is_deterministic_by_seed():
    spec = prepare_spec(load_scenario("highway_mixed_dense"), "cut_in").with_overrides(SHORT_HIGHWAY)
    a = run_episode(EpisodeJob(spec, 3, "const-vel"))
    b = run_episode(EpisodeJob(spec, 3, "const-vel"))
    c = run_episode(EpisodeJob(spec, 4, "const-vel"))
    assert a["scene"].equals(b["scene"])
    assert not a["scene"].equals(c["scene"])
    timing = ("wall_s", "cpu_s", "realtime_factor", "realtime_factor_with_warmup")
    strip = lambda s: {k: v for k, v in s.items() if k not in timing and not k.startswith("time_")}  # noqa: E731
    assert json.dumps(strip(a["scores"]), default=str) == json.dumps(strip(b["scores"]), default=str)
    s = a["scores"]
    assert s["ego_present"] and s["online_samples"] > 0 and np.isfinite(s["online_ade"])
    assert s["online_fde"] >= 0 and s["online_ade_rmse"] >= s["online_ade"] - 1e-9  # RMSE >= mean
    assert s["progress_m"] > 10.0  # the planner drove
    assert "car" in s["online_by_type"] or "motorcycle" in s["online_by_type"]


def test_bootstrap_ci_is_seeded_and_brackets_the_mean():
    x = [0.0, 1.0, 1.0, 0.0, 1.0, math.nan, 1.0]
    a, b = bootstrap_ci(x, seed=5), bootstrap_ci(x, seed=5)
    assert a == b and a["n"] == 6 and a["mean"] == pytest.approx(4 / 6)
    assert a["lo"] <= a["mean"] <= a["hi"] and a["hi"] - a["lo"] > 0
    assert math.isnan(bootstrap_ci([math.nan])["mean"])


def test_aggregate_keys_and_rates(queue_results):
    agg = aggregate([r["scores"] for r in queue_results["blind"]])
    for key in ("episodes", "collision_rate", "collisions_by_type", "near_miss_rate", "progress_m", "online_ade",
                "online_fde"):
        assert key in agg
    assert agg["episodes"] == 2 and agg["collision_rate"]["mean"] == 1.0
    assert sum(v["total"] for v in agg["collisions_by_type"].values()) >= 2
    assert math.isnan(agg["online_ade"]["mean"])  # the blind ego predicts nothing


def test_cli_writes_scores_episodes_animation_and_report(tmp_path):
    scenario = tmp_path / "hw.toml"
    text = Path(load_scenario("highway_mixed_dense").path).read_text()
    scenario.write_text(text.replace("duration = 60.0", "duration = 10.0").replace("warmup = 60.0", "warmup = 8.0")
                        + "\n[ego]\nenabled = true\ninsert_at = 2.0\nreaction = \"cut_in\"\n")
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "simharness", "closedloop", str(scenario), "--predictor",
                           "const-vel", "--seeds", "0-1", "--out", str(out), "--animate", "1", "--workers", "2"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "collision rate" in proc.stdout and "online ADE" in proc.stdout
    scores = json.loads((out / "scores.json").read_text())
    assert scores["episodes"] == 2 and scores["seeds"] == [0, 1]
    for key in ("collision_rate", "near_miss_rate", "progress_m", "online_ade", "online_fde"):
        assert {"mean", "lo", "hi"} <= set(scores[key])
    data = Dataset(out / "episodes")
    assert len(data) == 2 and data.scene(0).ego >= 0 and data.road is not None
    assert (out / "episode-seed000000.gif").stat().st_size > 10_000
    report = (out / "report.md").read_text()
    assert "scorecard.png" in report and (out / "scorecard.png").is_file()


def test_cli_bad_predictor_is_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "simharness", "closedloop", "highway_mixed_dense", "--predictor",
                           "no-such-model", "--out", str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "no-such-model" in proc.stderr
    assert not (tmp_path / "x").exists()


def test_loop_config_predict_rate_is_respected():
    spec = prepare_spec(load_scenario("highway_mixed_dense"), "reactive").with_overrides(SHORT_HIGHWAY)
    fast = run_episode(EpisodeJob(spec, 0, "const-vel", LoopConfig(predict_hz=5.0), keep_forecasts=True))
    slow = run_episode(EpisodeJob(spec, 0, "const-vel", LoopConfig(predict_hz=1.0), keep_forecasts=True))
    n_fast, n_slow = len(fast["forecasts"][0]), len(slow["forecasts"][0])
    assert n_fast > 4 * n_slow - 5 and n_slow > 0


def test_branch_oracle_is_exact_on_highway_when_ignored():
    # highway-env deep-copies: the oracle rolls a branch of the live simulator ahead.
    spec = prepare_spec(load_scenario("highway_mixed_dense"), "ignore").with_overrides(
        {**SHORT_HIGHWAY, "duration": 8.0})
    s = run_episode(EpisodeJob(spec, 1, "oracle", keep_scene=False))["scores"]
    assert s["online_samples"] > 0 and s["online_ade"] == pytest.approx(0.0, abs=1e-4)


def test_collision_boxes_take_the_simulators_body_heading():
    """Two cars 0.2 m apart side by side, edging sideways at walking pace: their heading of motion turns
    30 degrees, their (SUMO, lane-aligned) bodies do not; only the bodies are scored."""
    from simharness.closedloop import Issued

    t = 3
    xy = np.array([[[-40.0, 0.0]] * t, [[0.0, 1.0]] * t, [[0.0, -1.0]] * t])
    motion = np.zeros((3, t))
    motion[1:] = np.radians(30.0)
    scene = Scene(xy=xy, heading=motion, speed=np.ones((3, t)), valid=np.ones((3, t), bool),
                  agent_id=np.array(["ego", "a", "b"]), agent_type=np.full(3, AgentType.CAR),
                  length=np.full(3, 4.3), width=np.full(3, 1.8), dt=0.2, ego=0,
                  extra={"sim_heading": np.zeros((3, t), np.float32)})
    assert score_episode(scene, Issued(), LoopConfig())["background_collisions"] == 0
    scene_motion = scene.replace(extra={})  # a backend without sim_heading: its heading is the body's
    assert score_episode(scene_motion, Issued(), LoopConfig())["background_collisions"] == 1
