"""`simharness sweep`: grid building and validation, and a tiny grid end to end on both executors.

The end-to-end test runs the real closed loop (SUMO, constant-velocity predictor, sampling planner):
once through the CLI on its own Ray instance, once in-process on the local pool; the two must score
every episode the same.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from simharness.errors import UserError
from simharness.scenario import load_scenario
from simharness.sweep import METRICS, build_grid, parse_value, sweep


def _is_timing(key: str) -> bool:
    """Wall-clock figures of an episode (they differ run to run); time_stuck_s is a score, not a timing."""
    return key in ("wall_s", "cpu_s") or key.startswith("realtime_factor") or (
        key.startswith("time_") and key != "time_stuck_s")


@pytest.fixture(scope="module")
def spec():
    return load_scenario("sumo_arterial_dense")


def test_parse_value_reads_like_toml() -> None:
    assert [parse_value(v) for v in ("1", "0.5", "true", "cut_in", "2e1")] == [1, 0.5, True, "cut_in", 20.0]


def test_several_sets_multiply_first_axis_slowest(spec) -> None:
    grid = build_grid(spec, [("demand_scale", ["0.5", "1"]), ("ego.reaction", ["reactive", "ignore"])])
    assert grid == [{"demand_scale": 0.5, "ego.reaction": "reactive"}, {"demand_scale": 0.5, "ego.reaction": "ignore"},
                    {"demand_scale": 1, "ego.reaction": "reactive"}, {"demand_scale": 1, "ego.reaction": "ignore"}]


@pytest.mark.parametrize(("sets", "message"), [
    ([], "at least one --set"),
    ([("demand_scale", ["1"]), ("demand_scale", ["2"])], "given twice"),
    ([("demand_scale", [])], "no values"),
    ([("demand_scale", ["50"])], r"key 'demand_scale': expected a number in \[0.0, 20.0\], got 50"),
    ([("road.wdith", ["8"])], r"key 'road.wdith': unknown key"),
    ([("ego.reaction", ["polite"])], r"key 'ego.reaction': expected one of"),
    ([("demand.scale", ["1"])], r"key 'demand.scale': unknown agent type.*did you mean --set demand_scale="),
])
def test_bad_grid_is_one_clear_line(spec, sets, message) -> None:
    with pytest.raises(UserError, match=message) as e:
        build_grid(spec, sets)
    assert "\n" not in str(e.value)


def test_cli_bad_set_exits_2_before_any_episode(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, "-m", "simharness", "sweep", "sumo_arterial_dense", "--set",
                          "demand_scale=0.5,99", "--predictor", "const-vel", "--out", str(tmp_path / "sw")],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "demand_scale" in run.stderr and "Traceback" not in run.stderr
    assert not (tmp_path / "sw").exists()


def _comparable(episodes: list[dict]) -> str:
    """Every episode's scores but its wall-clock timings, as canonical JSON (NaN compares equal as text)."""
    return json.dumps([{k: v for k, v in e.items() if not _is_timing(k)} for e in episodes], sort_keys=True)


def test_sweep_end_to_end_on_ray_and_local(tmp_path: Path) -> None:
    scenario = tmp_path / "short.toml"
    text = Path(load_scenario("sumo_arterial_dense").path).read_text()
    scenario.write_text(text.replace("duration = 60.0", "duration = 4.0").replace("warmup = 90.0", "warmup = 10.0"))
    ray_out = tmp_path / "ray"
    run = subprocess.run([sys.executable, "-m", "simharness", "sweep", str(scenario), "--set", "demand_scale=0.5,1",
                          "--seeds", "0-1", "--predictor", "const-vel", "--executor", "ray", "--workers", "2",
                          "--out", str(ray_out)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert sorted(p.name for p in ray_out.iterdir()) == ["sweep.json", "sweep.md", "sweep.png"]
    assert (ray_out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = (ray_out / "sweep.md").read_text()
    assert "| demand_scale | predictor | episodes | collision rate |" in table
    assert "| 0.5 | const-vel | 2 |" in table and "| 1 | const-vel | 2 |" in table
    on_ray = json.loads((ray_out / "sweep.json").read_text())
    assert on_ray["info"]["axes"] == {"demand_scale": [0.5, 1]} and on_ray["info"]["seeds"] == [0, 1]
    assert on_ray["info"]["executor"] == "ray" and on_ray["info"]["versions"]["libsumo"]
    assert [p["settings"] for p in on_ray["points"]] == [{"demand_scale": 0.5}, {"demand_scale": 1}]
    assert len({p["config_hash"] for p in on_ray["points"]}) == 2  # each point is its own scenario config
    for p in on_ray["points"]:
        assert p["episodes_with_ego"] == 2 and not p["failed"]
        for name, _, _ in METRICS:
            ci = p[name]
            assert ci["n"] == 2 and ci["lo"] <= ci["mean"] <= ci["hi"], (name, ci)
        assert 0.0 <= p["collision_rate"]["mean"] <= 1.0 and p["online_ade"]["mean"] > 0
        assert p["progress_m"]["mean"] > 5  # the ego drove
    # The same grid in-process on the local pool: every episode scored the same.
    local = sweep(load_scenario(scenario), [("demand_scale", ["0.5", "1"])], ["const-vel"], [0, 1],
                  tmp_path / "local", workers=2, executor="local", progress=False)
    assert len(local["episodes"]) == 4
    assert _comparable(local["episodes"]) == _comparable(on_ray["episodes"])
    assert all(math.isclose(a["online_ade"]["mean"], b["online_ade"]["mean"])
               for a, b in zip(local["points"], on_ray["points"], strict=True))
