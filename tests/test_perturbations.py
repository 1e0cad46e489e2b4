"""Forecast perturbations: each does what it says, keeps shapes, is seeded; the sensitivity command runs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simharness.closedloop.perturbations import Perturbation, PerturbedPredictor, parse_grid, perturb, retime
from simharness.errors import UserError
from simharness.scene import AgentType, Forecast, Scene

H, F, DT = 5, 10, 0.2


def _history(n: int = 4) -> Scene:
    """n agents driving along +x at 1..n m/s, agent 0 a car, the rest alternating motorcycle/pedestrian."""
    t = np.arange(H) * DT
    speed = np.arange(1, n + 1, dtype=np.float64)
    xy = np.stack([speed[:, None] * t[None], np.repeat(np.arange(n)[:, None] * 3.0, H, 1)], -1)
    types = np.array([AgentType.CAR] + [AgentType.MOTORCYCLE if i % 2 else AgentType.PEDESTRIAN
                                        for i in range(1, n)], np.int8)
    return Scene(xy=xy.astype(np.float32), heading=np.zeros((n, H), np.float32),
                 speed=np.repeat(speed[:, None], H, 1).astype(np.float32), valid=np.ones((n, H), bool),
                 agent_id=np.array([f"a{i}" for i in range(n)]), agent_type=types,
                 length=np.full(n, 4.0, np.float32), width=np.full(n, 1.8, np.float32), dt=DT, ego=-1)


class ConstVel:
    """A real (tiny) predictor: constant velocity from the history's last step."""

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        v = history.xy[targets, -1] - history.xy[targets, -2]
        mean = history.xy[targets, -1][:, None] + v[:, None] * (np.arange(horizon) + 1)[None, :, None]
        sig = np.zeros((len(targets), horizon, 3), np.float32)
        sig[..., :2] = 0.5
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=history.dt,
                        sigma_rho=sig)


def _clean(hist: Scene) -> tuple[Forecast, np.ndarray]:
    targets = np.arange(hist.num_agents)
    return ConstVel().predict(hist, targets, F), targets


def _perturb(f: Forecast, hist: Scene, targets: np.ndarray, p: Perturbation, rng: np.random.Generator) -> Forecast:
    return perturb(f, hist.xy[targets, -1], hist.agent_type[targets], p,
                   unit_noise=rng.standard_normal((len(f.agent_id), 2)))


def test_identity_changes_nothing():
    hist = _history()
    f, targets = _clean(hist)
    out = _perturb(f, hist, targets, Perturbation(), np.random.default_rng(0))
    np.testing.assert_allclose(out.mean, f.mean, atol=1e-5)
    np.testing.assert_allclose(out.sigma_rho, f.sigma_rho)
    assert Perturbation().is_identity and Perturbation().label() == "none"


def test_noise_grows_with_lead_time_and_is_seeded():
    hist = _history(200)
    f, targets = _clean(hist)
    a = _perturb(f, hist, targets, Perturbation(noise=2.0), np.random.default_rng(7))
    b = _perturb(f, hist, targets, Perturbation(noise=2.0), np.random.default_rng(7))
    c = _perturb(f, hist, targets, Perturbation(noise=2.0), np.random.default_rng(8))
    np.testing.assert_array_equal(a.mean, b.mean)
    assert not np.allclose(a.mean, c.mean)
    err = a.mean - f.mean  # (M, F, 2)
    assert a.mean.shape == f.mean.shape
    std = err.reshape(-1, F, 2).std(axis=(0, 2))  # per step
    assert np.all(np.diff(std) > 0)  # grows with the lead time ...
    assert std[-1] == pytest.approx(2.0, rel=0.2)  # ... to the asked std at the last step
    assert std[0] == pytest.approx(2.0 / F, rel=0.3)


def test_speed_scales_displacement_and_heading_rotates_it():
    hist = _history()
    f, targets = _clean(hist)
    now = hist.xy[targets, -1][:, None]
    slow = _perturb(f, hist, targets, Perturbation(speed=0.5), np.random.default_rng(0))
    np.testing.assert_allclose(slow.mean - now, 0.5 * (f.mean - now), atol=1e-5)
    turned = _perturb(f, hist, targets, Perturbation(heading=90.0), np.random.default_rng(0))
    d0, d1 = f.mean - now, turned.mean - now
    np.testing.assert_allclose(d1[..., 0], -d0[..., 1], atol=1e-4)  # (x, y) -> (-y, x)
    np.testing.assert_allclose(d1[..., 1], d0[..., 0], atol=1e-4)


def test_drop_removes_one_type_and_sigma_scales():
    hist = _history(6)
    f, targets = _clean(hist)
    out = _perturb(f, hist, targets, Perturbation(drop="pedestrian", sigma=3.0), np.random.default_rng(0))
    kept = hist.agent_type != AgentType.PEDESTRIAN
    assert list(out.agent_id) == list(hist.agent_id[kept])
    assert out.mean.shape == (kept.sum(), F, 2) and out.sigma_rho.shape == (kept.sum(), F, 3)
    np.testing.assert_allclose(out.sigma_rho[..., :2], 1.5)
    np.testing.assert_allclose(out.sigma_rho[..., 2], 0.0)


def test_latency_serves_the_forecast_made_k_frames_ago():
    hist = _history(3)
    wrapped = PerturbedPredictor(ConstVel(), Perturbation(latency=2), seed=0)
    first = wrapped.predict(hist, np.arange(3), F)  # nothing older yet: the oldest kept, not re-timed
    assert first.mean.shape == (3, F, 2)
    later = hist.replace(xy=hist.xy + np.array([5.0, 0.0], np.float32), frame0=hist.frame0 + 2)
    out = wrapped.predict(later, np.arange(3), F)
    # Two frames late: the first forecast re-timed by 2 steps, extended at its last velocity.
    np.testing.assert_allclose(out.mean, retime(first, 2, F).mean)
    np.testing.assert_allclose(out.mean[:, : F - 2], first.mean[:, 2:])
    step = first.mean[:, -1] - first.mean[:, -2]
    np.testing.assert_allclose(out.mean[:, -1], first.mean[:, -1] + 2 * step, atol=1e-5)


def test_grid_and_bad_values():
    grid = parse_grid(["noise=0,1", "latency=0,2"])
    assert [g.label() for g in grid] == ["none", "latency=2", "noise=1", "noise=1,latency=2"]
    for bad in (["noise"], ["nois=1"], ["noise=-1"], ["latency=1.5"], ["drop=spaceship"], ["speed=x"]):
        with pytest.raises(UserError):
            parse_grid(bad)


@pytest.mark.slow
def test_sensitivity_cli_small_run(tmp_path):
    from simharness.cli import main

    scenario = tmp_path / "short.toml"
    from simharness.scenario import SCENARIO_DIR

    text = (SCENARIO_DIR / "stress" / "step_out.toml").read_text()
    scenario.write_text(text.replace("duration = 15.0", "duration = 4.0").replace("warmup = 20.0", "warmup = 2.0"))
    out = tmp_path / "sens"
    rc = main(["sensitivity", str(scenario), "--predictor", "const-vel", "--perturb", "noise=0,4",
               "--seeds", "0-1", "--workers", "1", "--out", str(out)])
    assert rc == 0
    table = json.loads((out / "sensitivity.json").read_text())
    rows = table["rows"]
    assert [r["perturbation"] for r in rows] == ["none", "noise=4"]
    assert all(r["episodes"] == 2 for r in rows)
    ade = [r["online_ade"]["mean"] for r in rows]
    assert all(math.isfinite(a) for a in ade) and ade[1] > ade[0] + 0.5  # the injected error is measured
    assert (out / "sensitivity.md").read_text().count("\n|") >= 3
    assert (out / "sensitivity.png").stat().st_size > 1000


@pytest.mark.slow
def test_perturbed_exact_oracle_serves_degraded_forecasts():
    """The branch oracle's forecasts are degraded too (what `sensitivity --predictor oracle` measures)."""
    from simharness.closedloop import EpisodeJob, prepare_spec, run_episode
    from simharness.scenario import load_scenario

    spec = prepare_spec(load_scenario("stress/step_out").with_overrides({"duration": 4.0, "warmup": 2.0}))
    clean = run_episode(EpisodeJob(spec, 0, "oracle", keep_scene=False))["scores"]
    noisy = run_episode(EpisodeJob(spec, 0, "oracle", keep_scene=False, perturbation=Perturbation(noise=4.0)))
    assert clean["online_ade"] < 0.1
    assert noisy["scores"]["online_ade"] > clean["online_ade"] + 1.0


def test_noise_is_fixed_by_seed_frame_and_agent():
    """The same (seed, frame, agent) draws the same error whatever else is in the forecast (branch and live agree)."""
    from simharness.closedloop.perturbations import Degrader, unit_normals

    ids = np.array([f"a{i}" for i in range(4000)])
    z = unit_normals(5, 12, ids)
    assert abs(z.mean()) < 0.05 and z.std() == pytest.approx(1.0, abs=0.05)
    np.testing.assert_array_equal(unit_normals(5, 12, ids[[7, 3]]), z[[7, 3]])
    assert not np.allclose(unit_normals(5, 13, ids[:50]), z[:50])
    assert not np.allclose(unit_normals(6, 12, ids[:50]), z[:50])
    hist = _history()
    f, targets = _clean(hist)
    a = Degrader(Perturbation(noise=1.0), seed=5).degrade(f, hist.xy[targets, -1], hist.agent_type[targets], 12, F)
    sub = Forecast(agent_id=f.agent_id[2:], mean=f.mean[2:], dt=f.dt)
    b = Degrader(Perturbation(noise=1.0), seed=5).degrade(sub, hist.xy[targets[2:], -1], hist.agent_type[targets[2:]],
                                                          12, F)
    np.testing.assert_allclose(b.mean, a.mean[2:], atol=1e-5)


def test_perturbed_oracle_branches_drive_on_the_degraded_forecasts():
    """Under a perturbation the live ego keeps following the oracle's branch (its ego is served the same errors)."""
    from simharness.closedloop import EpisodeJob, prepare_spec, run_episode
    from simharness.scenario import load_scenario

    spec = prepare_spec(load_scenario("stress/step_out"))
    s = run_episode(EpisodeJob(spec, 0, "oracle", keep_scene=False, perturbation=Perturbation(noise=2.0)))["scores"]
    assert s["online_ade"] > 0.5  # the errors are served ...
    assert s["oracle_mismatches"] == 0  # ... and the live episode stays on the branch its ego was driven on
