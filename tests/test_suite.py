"""`simharness stress` and the loop's checks on forecasts: the suite end to end on the real highway backend,
invalid forecasts refused as one line (exit 2), forecast coverage, strict JSON, paired verdicts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simharness.closedloop import LoopConfig, aggregate, make_planner, prepare_spec, score_episode, simulate
from simharness.closedloop.oracles import StaticForecast
from simharness.closedloop.validation import validate_forecast
from simharness.errors import UserError
from simharness.scenario import load_scenario
from simharness.scene import Forecast

NAN_PLUGIN = '''
import numpy as np
from simharness.scene import Forecast


class NanPredictor:
    def predict(self, history, targets, horizon):
        return Forecast(agent_id=history.agent_id[targets], mean=np.full((len(targets), horizon, 2), np.nan),
                        dt=history.dt)
'''


def strict_loads(text: str):
    def refuse(token: str):
        raise ValueError(f"not strict JSON: {token}")

    return json.loads(text, parse_constant=refuse)


def cli(*args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simharness", *args], capture_output=True, text=True,
                          timeout=timeout)


def test_stress_suite_end_to_end(tmp_path):
    out = tmp_path / "suite"
    proc = cli("stress", "--predictor", "static,none", "--scenarios", "brake,cut_in", "--seeds", "0-1",
               "--duration", "2", "--workers", "1", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    board = strict_loads((out / "leaderboard.json").read_text())
    info = board["info"]
    assert info["scenarios"] == ["brake", "cut_in"] and info["seeds"] == [0, 1]
    assert info["egos"] == ["static", "none", "const-vel"]  # the baseline joins the named egos
    assert info["references"] == ["none"]
    for sc in ("brake", "cut_in"):
        for ego in info["egos"]:
            assert [e["seed"] for e in board["episodes"][sc][ego]] == [0, 1]  # the same seeds for every ego
            assert board["scenarios"][sc][ego]["at_fault_collided"]["n"] == 2
    assert board["pooled"]["static"]["composite"]["n"] == 4
    # static minus const-vel, paired: per scenario and pooled, with a verdict
    p = board["paired"]["static"]
    assert set(p) == {"at_fault_collided", "collided", "composite"}
    assert p["composite"]["pooled"]["n"] == 4 and set(p["composite"]["scenarios"]) == {"brake", "cut_in"}
    assert p["at_fault_collided"]["pooled"]["verdict"] in (
        "no difference resolved at 4 episodes", "static is safer than const-vel", "const-vel is safer than static")
    assert board["pooled"]["none"]["online_ade"]["mean"] is None  # no forecasts: null, not NaN
    assert board["pooled"]["static"]["forecast_coverage"]["mean"] == 1.0
    md = (out / "leaderboard.md").read_text()
    assert "Verdicts against const-vel" in md and "Reference (the simulator's own driver" in md
    assert (out / "leaderboard.png").stat().st_size > 10_000
    assert "no difference resolved" in proc.stdout or "safer than" in proc.stdout


def test_stress_runs_a_learned_planner_as_an_ego_paired_with_the_baseline(tmp_path):
    out = tmp_path / "suite"
    proc = cli("stress", "--predictor", "const-vel", "--planner", "ppo", "--scenarios", "brake", "--seeds", "0-1",
               "--duration", "2", "--workers", "1", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    board = strict_loads((out / "leaderboard.json").read_text())
    assert board["info"]["egos"] == ["const-vel", "ppo"]
    eps = board["episodes"]["brake"]["ppo"]
    assert [e["seed"] for e in eps] == [0, 1] and {e["planner"] for e in eps} == {"ppo"}
    assert {e["planner"] for e in board["episodes"]["brake"]["const-vel"]} == {"pdm"}
    assert board["paired"]["ppo"]["composite"]["pooled"]["n"] == 2
    clash = cli("stress", "--predictor", "const-vel", "--planner", "const-vel", "--scenarios", "brake",
                "--out", str(tmp_path / "x"))
    assert clash.returncode == 2 and "--planner" in clash.stderr and clash.stderr.strip().count("\n") == 0


def test_stress_bad_resolve_is_one_line(tmp_path):
    proc = cli("stress", "--predictor", "static", "--until-resolved", "--resolve", "nobody", "--scenarios", "brake",
               "--out", str(tmp_path / "x"))
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0 and "--resolve" in proc.stderr


def test_nan_forecasting_plugin_is_refused_with_exit_2(tmp_path):
    plugin = tmp_path / "nanpred.py"
    plugin.write_text(NAN_PLUGIN)
    name = f"{plugin}:NanPredictor"
    scenario = tmp_path / "short.toml"
    scenario.write_text(Path(load_scenario("stress/brake").path).read_text().replace("duration = 15.0",
                                                                                     "duration = 2.0"))
    proc = cli("closedloop", str(scenario), "--predictor", name, "--seeds", "0", "--workers", "1",
               "--out", str(tmp_path / "run"))
    assert proc.returncode == 2, proc.stderr[-2000:]
    line = proc.stderr.strip().splitlines()[-1]  # after the progress bar
    assert line.startswith("simharness: error: predictor") and "Traceback" not in proc.stderr
    assert "NanPredictor" in line and "NaN" in line and "failed" not in line


def test_scores_json_is_strict_and_paired_verdicts_are_written(tmp_path):
    scenario = tmp_path / "short.toml"
    scenario.write_text(Path(load_scenario("stress/cut_in").path).read_text().replace("duration = 15.0",
                                                                                      "duration = 2.0"))
    out = tmp_path / "run"
    proc = cli("closedloop", str(scenario), "--predictor", "none,const-vel", "--seeds", "0", "--workers", "1",
               "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    none = strict_loads((out / "none" / "scores.json").read_text())
    assert none["online_ade"]["mean"] is None and none["forecast_coverage"]["mean"] is None
    cv = strict_loads((out / "const-vel" / "scores.json").read_text())
    assert cv["forecast_coverage"]["mean"] == 1.0 and cv["online_ade"]["mean"] > 0
    card = strict_loads((out / "scorecard.json").read_text())
    assert card["paired"]["none"]["at_fault_collided"]["pooled"]["n"] == 1
    assert "none minus const-vel, paired on seeds" in proc.stdout


class HalfPredictor:
    """Forecasts the first half of its targets only (constant position): coverage ~0.5."""

    def predict(self, history, targets, horizon):
        keep = targets[: (len(targets) + 1) // 2]
        return Forecast(agent_id=history.agent_id[keep],
                        mean=np.repeat(history.xy[keep, -1:], horizon, axis=1).astype(np.float32), dt=history.dt)


def test_aggregate_takes_score_episode_output_and_reports_coverage():
    spec = prepare_spec(load_scenario("stress/brake")).with_overrides({"duration": 3.0})
    cfg = LoopConfig()
    rows = []
    for predictor in (StaticForecast(), HalfPredictor()):
        scene, issued, _, _ = simulate(spec, 0, predictor, make_planner("static", spec, None), cfg)
        rows.append(score_episode(scene, issued, cfg))  # no seed, no timings: not what run_episode adds
    assert rows[0]["forecast_coverage"] == 1.0
    assert 0.4 < rows[1]["forecast_coverage"] < 0.9
    agg = aggregate(rows)
    assert agg["episodes"] == 2 and agg["seeds"] == []
    assert agg["forecast_coverage"]["n"] == 2 and agg["realtime_factor"]["n"] == 0
    assert np.isfinite(agg["composite"]["mean"])


def _forecast(ids, mean, sigma=None):
    return Forecast(agent_id=np.asarray(ids), mean=np.asarray(mean, np.float32), dt=0.2, sigma_rho=sigma)


@pytest.mark.parametrize("forecast, fault", [
    (None, "returned NoneType"),
    (_forecast(["a"], np.full((1, 5, 2), np.inf)), "NaN or infinite"),
    (_forecast(["a"], np.zeros((1, 5, 2)), np.full((1, 5, 3), np.nan)), "sigma_rho"),
    (_forecast(["a"], np.zeros((1, 3, 2))), "covers 3 frames; 5 were asked for"),
    (_forecast(["a", "z"], np.zeros((2, 5, 2))), "agent z, which is not among"),
    (_forecast(["a", "a"], np.zeros((2, 5, 2))), "the same agent twice"),
])
def test_validate_forecast_names_the_predictor_and_the_fault(forecast, fault):
    with pytest.raises(UserError, match="mine") as e:
        validate_forecast(forecast, "mine", np.array(["a", "b"]), 5)
    assert fault in str(e.value)
    ok = _forecast(["b"], np.zeros((1, 6, 2)))
    assert validate_forecast(ok, "mine", np.array(["a", "b"]), 5) is ok
