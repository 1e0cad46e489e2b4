"""The planners on hand-built situations: brake for a blocked road, swerve into a gap, keep to the road, plan
around agents the forecast left out, command smoothly (PDM), use sigma (sampling)."""

from __future__ import annotations

import numpy as np

from simharness.pdm_planner import PDMPlanner
from simharness.planners import BackgroundPlanner, ConstantSpeedPlanner, EgoLimits, Planner, SamplingPlanner
from simharness.scene import AgentType, Forecast, Scene
from simharness.sim.base import EgoCommand, RoadGeometry


def _now(ego_speed: float, others: list[tuple[float, float, float]]) -> Scene:
    """One-frame scene: ego (row 0) at the origin heading +x; others (x, y, speed) heading +x, 4.3 x 1.8 m."""
    xy = np.array([[0.0, 0.0]] + [[x, y] for x, y, _ in others])[:, None]
    n = xy.shape[0]
    return Scene(xy=xy, heading=np.zeros((n, 1)), speed=np.array([[ego_speed]] + [[v] for *_, v in others]),
                 valid=np.ones((n, 1), bool), agent_id=["ego"] + [f"a{i}" for i in range(n - 1)],
                 agent_type=np.full(n, AgentType.CAR), length=np.full(n, 4.3), width=np.full(n, 1.8), dt=0.2, ego=0)


def _cv_forecast(now: Scene, frames: int = 25, sigma: float | None = None) -> Forecast:
    rows = np.arange(1, now.num_agents)
    t = (np.arange(frames) + 1) * 0.2
    mean = now.xy[rows, -1][:, None] + now.speed[rows, -1][:, None, None] * np.stack([t, 0 * t], -1)[None]
    sr = None
    if sigma is not None:
        sr = np.zeros((rows.size, frames, 3), np.float32)
        sr[..., :2] = sigma
    return Forecast(agent_id=now.agent_id[rows], mean=mean.astype(np.float32), dt=0.2, sigma_rho=sr)


def _road(half_width: float) -> RoadGeometry:
    poly = np.array([[-100, -half_width], [400, -half_width], [400, half_width], [-100, half_width]], float)
    return RoadGeometry(drivable=(poly,))


def test_brakes_for_a_stopped_wall_across_the_road():
    wall = [(25.0, y, 0.0) for y in (-4.0, -2.0, 0.0, 2.0, 4.0)]
    now = _now(10.0, wall)
    planner = SamplingPlanner(EgoLimits(max_speed=14.0), road=_road(5.0))
    cmd = planner.plan(now, _cv_forecast(now))
    assert cmd.acceleration <= -2.5
    # The chosen rollout stops short of the wall (front bumper before its rear bumper).
    assert planner.last_rollout[:, 0].max() + 4.3 / 2 < 25.0 - 4.3 / 2


def test_speeds_up_on_an_empty_road_and_keeps_its_line():
    now = _now(5.0, [])
    cmd = SamplingPlanner(EgoLimits(max_speed=14.0), road=_road(5.0)).plan(now, _cv_forecast(now))
    assert cmd.acceleration > 0 and cmd.lateral_velocity == 0


def test_swerves_into_a_free_gap_rather_than_stopping():
    # A stopped car dead ahead, free space to the left.
    now = _now(10.0, [(25.0, 0.0, 0.0), (25.0, -2.2, 0.0)])
    planner = SamplingPlanner(EgoLimits(max_speed=14.0), road=_road(5.0))
    cmd = planner.plan(now, _cv_forecast(now))
    assert cmd.lateral_velocity > 0
    assert planner.last_rollout[-1, 0] > 25.0  # gets past


def test_road_edge_is_respected():
    # Same, but the road ends just left of the ego: the swerve is impossible, so it brakes.
    now = _now(10.0, [(25.0, 0.0, 0.0), (25.0, -2.2, 0.0)])
    cmd = SamplingPlanner(EgoLimits(max_speed=14.0), road=_road(1.5)).plan(now, _cv_forecast(now))
    assert cmd.lateral_velocity <= 0 and cmd.acceleration < 0


def test_forecast_uncertainty_widens_the_others():
    # A car passing 2.6 m to the left at the same speed: fine when certain, a conflict with sigma 1 m.
    now = _now(10.0, [(0.0, 2.6, 10.0)])
    sure = SamplingPlanner(EgoLimits(max_speed=10.0), road=_road(6.0))
    sure.plan(now, _cv_forecast(now))
    unsure = SamplingPlanner(EgoLimits(max_speed=10.0), road=_road(6.0))
    cmd = unsure.plan(now, _cv_forecast(now, sigma=1.0))
    straight = np.flatnonzero((unsure._off == 0) & (unsure._acc == 0))[0]
    assert unsure.last_cost[straight] > sure.last_cost[straight] + 1.0
    assert cmd.lateral_velocity < 0  # moves away from the uncertain neighbour


def test_reference_planners_follow_the_protocol():
    now = _now(5.0, [])
    for p in (BackgroundPlanner(), ConstantSpeedPlanner(), SamplingPlanner()):
        assert isinstance(p, Planner)
    assert BackgroundPlanner().plan(now, None) is None
    assert ConstantSpeedPlanner().plan(now, None) == EgoCommand(0.0, 0.0)


def test_plan_is_deterministic_and_vectorised_over_many_agents():
    rng = np.random.default_rng(0)
    others = [(float(x), float(y), float(v)) for x, y, v in
              zip(rng.uniform(-40, 60, 80), rng.uniform(-5, 5, 80), rng.uniform(0, 12, 80), strict=True)]
    now = _now(8.0, others)
    a = SamplingPlanner(road=_road(6.0)).plan(now, _cv_forecast(now, sigma=0.5))
    b = SamplingPlanner(road=_road(6.0)).plan(now, _cv_forecast(now, sigma=0.5))
    assert a == b


def test_uncertainty_counts_along_its_own_axis():
    # A car 2.6 m to the left: lateral uncertainty (sigma_y) puts it in our path, longitudinal (sigma_x) does not.
    now = _now(10.0, [(0.0, 2.6, 10.0)])
    costs = {}
    for name, (sx, sy) in {"along": (1.5, 0.1), "across": (0.1, 1.5)}.items():
        fc = _cv_forecast(now, sigma=0.0)
        fc.sigma_rho[..., 0], fc.sigma_rho[..., 1] = sx, sy
        planner = SamplingPlanner(EgoLimits(max_speed=10.0), road=_road(6.0))
        planner.plan(now, fc)
        costs[name] = planner.last_cost[np.flatnonzero((planner._off == 0) & (planner._acc == 0))[0]]
    assert costs["across"] > costs["along"] + 1.0


def test_no_hard_stop_in_front_of_a_fast_follower_for_a_slow_leader():
    # A slower car 30 m ahead in our line, a fast one 6 m behind: ease off, do not slam the brakes.
    now = _now(10.0, [(30.0, 0.0, 6.0), (-10.3, 0.0, 10.0)])
    planner = SamplingPlanner(EgoLimits(max_speed=14.0), road=_road(1.5))
    cmd = planner.plan(now, _cv_forecast(now))
    assert cmd.acceleration > -4.5
    # Without the follower the same leader is no reason for a hard stop either, but the follower's term is live:
    hard = np.flatnonzero((planner._acc == -7.0) & (planner._off == 0))[0]
    alone = SamplingPlanner(EgoLimits(max_speed=14.0), road=_road(1.5))
    ahead_only = _now(10.0, [(30.0, 0.0, 6.0)])
    alone.plan(ahead_only, _cv_forecast(ahead_only))
    assert planner.last_cost[hard] > alone.last_cost[hard] + 5.0


def test_pair_terms_are_numpys_full_evaluation_to_the_bit():
    """The compiled pair terms (collision probability and headway shortfall of every candidate x agent x step) are
    the same floats as numpy's broadcast evaluation of the same formulas everywhere, the normal CDFs included, over
    near, far, ahead, behind and beside agents, with per-agent and shared sigmas."""
    from scipy.special import ndtr

    from simharness.planners import _NDTR_ONE, _NDTR_ZERO, _pair_terms

    probe = np.concatenate([np.linspace(_NDTR_ONE, 60.0, 200_001), [np.inf]])
    assert (ndtr(probe) == 1.0).all() and (ndtr(-probe - (_NDTR_ONE - _NDTR_ZERO)) == 0.0).all()
    rng = np.random.default_rng(3)
    n_c, n_m, n_f = 49, 30, 20
    exy, axy = rng.normal(0, 3, (n_c, n_f, 2)), rng.normal(0, (25, 6), (n_m, n_f, 2))
    eh, ah = rng.normal(0, 0.2, (n_c, n_f)), rng.uniform(-np.pi, np.pi, (n_m, n_f))
    la, wa = rng.uniform(0.3, 6, n_m), rng.uniform(0.3, 1.3, n_m)
    ev, counted = rng.uniform(0, 14, (n_c, n_f)), rng.random(n_m) < 0.8
    along0, lat0, margin, want = 2.75, 1.1, 0.5, 2.0 + 1.0 * ev
    ce, se, ca, sa = np.cos(eh), np.sin(eh), np.cos(ah), np.sin(ah)
    for s_along, s_lat in ((rng.uniform(0.2, 3, (n_c, n_m, n_f)), rng.uniform(0.2, 2, (n_c, n_m, n_f))),
                           (rng.uniform(0.2, 0.6, (n_c, 1, n_f)), rng.uniform(0.2, 0.6, (n_c, 1, n_f)))):
        # numpy, every pair: what SamplingPlanner._interaction_cost evaluated before the kernel
        cx, sx, cy, sy = ce[:, None], se[:, None], ca[None], sa[None]
        rx, ry = axy[None, ..., 0] - exy[:, None, :, 0], axy[None, ..., 1] - exy[:, None, :, 1]
        along, lat = rx * cx + ry * sx, ry * cx - rx * sx
        cos_dh, sin_dh = np.abs(cy * cx + sy * sx), np.abs(sy * cx - cy * sx)
        half_along = along0 + cos_dh * la[None, :, None] + sin_dh * wa[None, :, None]
        half_lat = lat0 + sin_dh * la[None, :, None] + cos_dh * wa[None, :, None]
        full = (ndtr((half_along - along) / s_along) - ndtr((-half_along - along) / s_along)) * (
            ndtr((half_lat - lat) / s_lat) - ndtr((-half_lat - lat) / s_lat))
        full = np.where(counted[None, :, None], full, 0.0)
        ahead = (along > 0) & (np.abs(lat) < half_lat)
        w = np.broadcast_to(want[:, None], along.shape)
        short = np.maximum(w - ((np.abs(along) - half_along) + margin), 0.0)
        short2 = np.where(ahead, (short / np.maximum(w, 1.0)) ** 2, 0.0)

        live, a1, b1, a2, b2, got2 = _pair_terms(exy, ce, se, axy, ca, sa, la, wa, along0, lat0, s_along, s_lat,
                                                 counted, want, margin)
        got = np.zeros(full.size)
        got[live] = (ndtr(a1) - ndtr(b1)) * (ndtr(a2) - ndtr(b2))
        assert np.array_equal(got.reshape(full.shape), full) and 0 < (full > 0).mean() and live.size < full.size
        assert np.array_equal(got2, short2) and 0 < (short2 > 0).mean() < 0.5


# ---------------------------------------------------------------------- PDMPlanner (the closed loop's default)
def _pdm(max_speed: float = 14.0, half_width: float = 5.0) -> PDMPlanner:
    return PDMPlanner(EgoLimits(max_speed=max_speed), road=_road(half_width))


def _drive(planner: PDMPlanner, now: Scene, forecast: Forecast | None, frames: int) -> list[EgoCommand]:
    """Replan `frames` times on the same scene (the ego stays put): the command sequence the tracking gives."""
    return [planner.plan(now, forecast) for _ in range(frames)]


def test_pdm_brakes_comfortably_for_a_stopped_wall_and_stops_short_of_it():
    wall = [(30.0, y, 0.0) for y in (-4.0, -2.0, 0.0, 2.0, 4.0)]
    now = _now(10.0, wall)
    planner = _pdm()
    cmd = planner.plan(now, _cv_forecast(now))
    # The first command moves off the current acceleration (0) by at most one comfortable jerk step.
    assert -planner.config.comfort_jerk * 0.2 - 1e-9 <= cmd.acceleration < 0
    assert planner.last_rollout[:, 0].max() + 4.3 / 2 < 30.0 - 4.3 / 2


def test_pdm_speeds_up_on_an_empty_road_and_keeps_its_line():
    now = _now(5.0, [])
    cmd = _pdm().plan(now, _cv_forecast(now))
    assert cmd.acceleration > 0 and cmd.lateral_velocity == 0


def test_pdm_goes_round_a_stopped_car_rather_than_stopping():
    now = _now(10.0, [(35.0, 0.0, 0.0), (35.0, -2.2, 0.0)])
    planner = _pdm()
    cmd = planner.plan(now, _cv_forecast(now))
    assert cmd.lateral_velocity > 0 and cmd.acceleration > -1.0
    assert planner.last_rollout[-1, 1] >= 1.8 and planner.last_rollout[-1, 0] > 30.0  # beside it, still going


def test_pdm_keeps_to_the_drivable_area():
    now = _now(10.0, [(25.0, 0.0, 0.0), (25.0, -2.2, 0.0)])
    planner = _pdm(half_width=1.5)
    cmd = planner.plan(now, _cv_forecast(now))
    assert cmd.lateral_velocity <= 0 and cmd.acceleration < 0
    assert (np.abs(planner.last_rollout[:, 1]) <= 1.5).all()


def test_pdm_plans_around_agents_the_forecast_left_out():
    # A stopped car dead ahead that the predictor did not forecast (and no forecast at all): still avoided.
    now = _now(10.0, [(25.0, 0.0, 0.0), (25.0, -2.2, 0.0), (25.0, 2.2, 0.0)])
    dropped = _cv_forecast(now)
    dropped = Forecast(agent_id=dropped.agent_id[1:], mean=dropped.mean[1:], dt=dropped.dt)
    for forecast in (dropped, None):
        planner = _pdm(half_width=3.3)
        planner.plan(now, forecast)
        assert planner.last_rollout[:, 0].max() + 4.3 / 2 < 25.0 - 4.3 / 2
    # The forecast still counts where it has the agent: told the car ahead drives off, the ego does not stop.
    moving = _cv_forecast(now)
    moving.mean[0] += np.stack([np.arange(1, 26) * 0.2 * 12.0, np.zeros(25)], -1).astype(np.float32)
    planner = _pdm(half_width=3.3)
    planner.plan(now, moving)
    assert planner.last_rollout[-1, 0] > 25.0


def test_pdm_commands_are_smooth_unless_a_collision_forces_them():
    # A slower car cuts into the lane 12 m ahead: the ego brakes within nuPlan's comfort bounds.
    now = _now(10.0, [(14.0, 2.0, 6.0)])
    fc = _cv_forecast(now)
    fc.mean[0, :, 1] = np.maximum(2.0 - 1.5 * np.arange(1, 26) * 0.2, 0.0)
    acc = np.array([c.acceleration for c in _drive(_pdm(), now, fc, 15)])
    jerk = np.abs(np.diff(np.concatenate([[0.0], acc]))) / 0.2
    assert acc.min() < -0.5 and np.abs(acc).max() <= 4.05 and jerk.max() <= 8.37


def test_pdm_slows_for_a_crosser_before_it_enters_its_corridor():
    # A pedestrian 30 m ahead crosses from the left at 1.5 m/s: in the ego's corridor within a second.
    from simharness.pdm_planner import PDMConfig

    now = _now(10.0, [(30.0, 3.0, 0.0)])
    t = np.arange(1, 26) * 0.2
    mean = np.stack([np.full(25, 30.0), 3.0 - 1.5 * t], -1)[None].astype(np.float32)
    fc = Forecast(agent_id=now.agent_id[1:], mean=mean, dt=0.2)
    first = {la: PDMPlanner(EgoLimits(max_speed=14.0), PDMConfig(leader_lookahead_s=la), road=_road(5.0)).plan(
        now, fc).acceleration for la in (0.0, 1.5)}
    assert first[1.5] < 0.0 < first[0.0]  # followed from before it enters, not only once it is in the way


def test_pdm_waits_for_a_pedestrian_forecast_to_cross_from_further_out():
    # A pedestrian stands at the right kerb 35 m ahead, forecast to walk across in 1.6 s: in the ego's corridor
    # about 2.4 s from now. Yielded to now (pedestrian_lookahead_s); a car doing the same, or a pedestrian walking
    # along the kerb, is not followed yet.
    from simharness.pdm_planner import PDMConfig

    def first_command(agent: AgentType, crosses: bool, config: PDMConfig) -> float:
        now = _now(10.0, [(35.0, -3.0, 0.0)])
        now.agent_type[1] = agent
        now.length[1], now.width[1] = (0.5, 0.5) if agent == AgentType.PEDESTRIAN else (4.3, 1.8)
        t = np.arange(1, 26) * 0.2
        walk = 2.0 * np.maximum(t - 1.6, 0.0)
        y, x = (-3.0 + walk, np.full(25, 35.0)) if crosses else (np.full(25, -3.0), 35.0 + walk)
        fc = Forecast(agent_id=now.agent_id[1:], mean=np.stack([x, y], -1)[None].astype(np.float32), dt=0.2)
        return PDMPlanner(EgoLimits(max_speed=14.0), config, road=_road(5.0)).plan(now, fc).acceleration

    default, short = PDMConfig(), PDMConfig(pedestrian_lookahead_s=1.5)
    assert first_command(AgentType.PEDESTRIAN, True, default) < 0.0 <= first_command(AgentType.PEDESTRIAN, True, short)
    assert first_command(AgentType.CAR, True, default) >= 0.0
    assert first_command(AgentType.PEDESTRIAN, False, default) == first_command(AgentType.PEDESTRIAN, False, short)


def test_pdm_escapes_off_the_road_only_when_every_road_proposal_collides():
    # A car comes head-on down the ego's line on a 4 m road: braking cannot avoid it, the shoulder can.
    now = _now(10.0, [(60.0, 0.0, -15.0)])
    fc = _cv_forecast(now)
    narrow = _pdm(half_width=2.0)
    narrow.plan(now, fc)
    assert np.abs(narrow.last_rollout[-1, 1]) > 2.0  # ends off the road, clear of the car
    wide = _pdm(half_width=6.0)
    wide.plan(now, fc)
    assert wide.last_score.max() > 0  # a road wide enough: a safe proposal on it, no escape needed


def test_pdm_is_deterministic_and_copyable():
    import copy
    import pickle

    rng = np.random.default_rng(0)
    others = [(float(x), float(y), float(v)) for x, y, v in
              zip(rng.uniform(-40, 60, 80), rng.uniform(-5, 5, 80), rng.uniform(0, 12, 80), strict=True)]
    now = _now(8.0, others)
    fc = _cv_forecast(now)
    a = _pdm()
    a.plan(now, fc)
    b, c = copy.deepcopy(a), pickle.loads(pickle.dumps(a))
    assert a.plan(now, fc) == b.plan(now, fc) == c.plan(now, fc)
    assert isinstance(a, Planner)


def test_make_planner_defaults_to_pdm_and_keeps_sampling():
    from simharness.closedloop.episode import make_planner
    from simharness.scenario import load_scenario

    spec = load_scenario("scenarios/stress/cut_in.toml")
    assert isinstance(make_planner("const-vel", spec, None), PDMPlanner)
    assert isinstance(make_planner("oracle", spec, None, kind="sampling"), SamplingPlanner)
    assert isinstance(make_planner("none", spec, None), BackgroundPlanner)


def test_the_episode_ends_as_completed_when_the_ego_reaches_the_end_of_its_road():
    from simharness.closedloop.config import LoopConfig
    from simharness.closedloop.episode import make_planner, prepare_spec, simulate
    from simharness.scenario import load_scenario

    spec = prepare_spec(load_scenario("scenarios/stress/cut_in.toml")).with_overrides(
        {"road.length": 200.0, "duration": 30.0, "warmup": 5.0, "events": []})
    scene, _, road, _ = simulate(spec, 0, None, make_planner("blind", spec, None), LoopConfig())
    e = scene.ego
    assert scene.num_frames < spec.num_frames  # ended early ...
    assert scene.valid[e].all() and scene.speed[e, -1] > 5.0  # ... driving, not stuck at the road's end
    end = max(p[:, 0].max() for p in road.drivable)
    assert end - spec.road.speed_limit * 4.0 - 5.0 <= scene.xy[e, -1, 0] < end - 20.0
