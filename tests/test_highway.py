"""highway-env backend: real HeteroHighwayEnv / HighwaySimulator runs, scored from the recorded Scene."""

from __future__ import annotations

import numpy as np
import pytest

from simharness.errors import UserError
from simharness.metrics.collisions import collision_events, collision_matrix
from simharness.scenario import load_scenario
from simharness.scene import DEFAULT_FOOTPRINT, AgentType, Scene
from simharness.sim import EgoCommand, Simulator, make_simulator, scene_from_frames
from simharness.sim.highway.agents import AGENT_CLASSES, HeteroAgent, hex_rgb
from simharness.sim.highway.simulator import HeteroHighwayEnv, HighwaySimulator
from simharness.style import TYPE_COLORS

PED = int(AgentType.PEDESTRIAN)


def run(spec, seed: int = 0, commands=None) -> tuple[Scene, HighwaySimulator]:
    """Record a whole scene; commands: optional callable frame_index -> EgoCommand | None."""
    sim = make_simulator(spec)
    frames = [sim.reset(seed)]
    for k in range(1, spec.num_frames):
        frames.append(sim.step(commands(k) if commands else None))
    sim.close()
    return scene_from_frames(frames, spec.dt, {"seed": seed}), sim


def short(name: str = "highway_mixed_dense", **overrides):
    base = {"warmup": 20.0, "duration": 10.0}
    base.update(overrides)
    return load_scenario(name).with_overrides(base)


def test_protocol_and_frames():
    spec = short(duration=2.0)
    sim = make_simulator(spec)
    assert isinstance(sim, HighwaySimulator) and isinstance(sim, Simulator)
    f0 = sim.reset(0)
    f1 = sim.step()
    assert (f0.t, f1.t, sim.dt) == (0.0, 0.2, 0.2)
    assert f1.num_agents > 20 and f1.xy.shape == (f1.num_agents, 2) and f1.xy.dtype == np.float32
    np.testing.assert_array_equal(f1.extra["lateral_offset"], f1.xy[:, 1])  # centre line at y = 0
    on_road = np.abs(f1.xy[:, 1]) <= spec.road.width / 2
    assert on_road[f1.agent_type != PED].all()  # vehicles never leave the carriageway
    for t in np.unique(f1.agent_type):  # real footprints per type
        m = f1.agent_type == t
        assert np.allclose(f1.length[m], DEFAULT_FOOTPRINT[AgentType(t)][0])
    assert sim.road.on_road(np.array([[10.0, 0.0], [10.0, spec.road.width]])).tolist() == [True, False]
    sim.close()


def test_same_seed_same_scene_other_seed_differs():
    spec = short(duration=6.0)
    a, _ = run(spec, 3)
    b, _ = run(spec, 3)
    c, _ = run(spec, 4)
    assert a.equals(b)
    assert not a.equals(c)


def test_ids_stable_and_never_reused():
    scene, _ = run(short(duration=20.0))
    # A reused id would merge two tracks into one with a hole: every track is one contiguous run.
    v = scene.valid.astype(np.int8)
    starts = np.diff(np.pad(v, ((0, 0), (1, 0))), axis=1) == 1
    assert (starts.sum(1) == 1).all()
    assert scene.valid[:, 0].sum() < scene.num_agents  # agents did enter and leave during the scene
    uids = np.array([int(a.rsplit("_", 1)[1]) for a in scene.agent_id])
    assert np.unique(uids).size == uids.size


def test_mixed_scenario_meets_density_targets(tmp_path):
    from simharness.generation import generate
    from simharness.stats import dataset_stats

    spec = load_scenario("highway_mixed_dense").with_overrides({"duration": 20.0})
    summary = generate(spec, [0], tmp_path / "ds", workers=1, progress=False)
    assert summary["done"] == 1, summary
    st = dataset_stats(tmp_path / "ds")
    assert st["agents_within_50m"] >= 15, st["agents_within_50m"]
    assert st["density_per_km"] >= 100, st["density_per_km"]
    assert st["distinct_types_per_frame"]["min"] >= 5, st["distinct_types_per_frame"]
    assert st["collisions"]["box_overlap"] == 0, st["collisions"]


def test_small_vehicles_filter_past_large_ones():
    scene, _ = run(short(duration=20.0))
    small = np.flatnonzero(np.isin(scene.agent_type, [AgentType.MOTORCYCLE, AgentType.SCOOTER]))
    large = np.flatnonzero(np.isin(scene.agent_type, [AgentType.BUS, AgentType.TRUCK, AgentType.CAR]))
    x, y = scene.xy[..., 0], scene.xy[..., 1]
    both = scene.valid[small][:, None] & scene.valid[large][None, :]
    ahead = x[small][:, None] > x[large][None, :]
    passing = both[..., 1:] & both[..., :-1] & ahead[..., 1:] & ~ahead[..., :-1]  # (S, G, T-1)
    s_i, g_i, t_i = np.nonzero(passing)
    assert s_i.size >= 10, f"only {s_i.size} passes of large vehicles by two-wheelers"
    # A pass happens beside the large vehicle: the boxes are laterally apart at that instant.
    lat_gap = np.abs(y[small[s_i], t_i + 1] - y[large[g_i], t_i + 1]) - \
        0.5 * (scene.width[small[s_i]] + scene.width[large[g_i]])
    assert (lat_gap > 0).all()


def test_pedestrians_cross_and_are_not_hit():
    spec = short(duration=30.0, **{"pedestrians.crossing_rate": 900.0})
    crossed = 0
    for seed in range(3):
        scene, _ = run(spec, seed)
        peds = np.flatnonzero(scene.agent_type == PED)
        y = scene.xy[peds, :, 1]
        first = np.take_along_axis(y, scene.valid[peds].argmax(1)[:, None], 1)[:, 0]
        ever_left = np.where(scene.valid[peds], y, -np.inf).max(1)
        ever_right = np.where(scene.valid[peds], y, np.inf).min(1)
        h = spec.road.width / 2
        # from a sidewalk across the whole carriageway, to within 1 m of the far edge
        crossed += int(((first < -h) & (ever_left > h - 1)).sum() + ((first > h) & (ever_right < 1 - h)).sum())
        ev = collision_events(scene.xy, scene.heading, scene.length, scene.width, scene.valid)
        with_ped = (scene.agent_type[ev[:, 1]] == PED) | (scene.agent_type[ev[:, 2]] == PED)
        assert not with_ped.any(), f"seed {seed}: pedestrian hit: {ev[with_ped]}"
    assert crossed >= 5, f"only {crossed} pedestrians crossed"


def test_render_not_blank():
    spec = short(duration=1.0)
    sim = make_simulator(spec)
    frame = sim.reset(0)
    img = sim.render()
    sim.close()
    assert img.shape == (240, 1200, 3) and img.dtype == np.uint8
    colours = {tuple(c) for c in np.unique(img.reshape(-1, 3), axis=0)}
    assert len(colours) >= 6
    assert (255, 255, 255) in colours  # road markings
    present = {AgentType(int(t)) for t in frame.agent_type}
    drawn = [t for t in present if hex_rgb(TYPE_COLORS[t]) in colours]
    assert len(drawn) >= 4, f"type colours drawn: {drawn} of {present}"


def test_ego_commands_and_reactions():
    spec = short(duration=6.0, **{"ego.enabled": True, "ego.insert_at": 0.0, "ego.speed": 6.0})
    sim = make_simulator(spec)
    f = sim.reset(1)
    assert f.ego >= 0 and f.agent_id[f.ego] == "ego"
    v0, y0 = float(f.speed[f.ego]), float(f.xy[f.ego, 1])
    for _ in range(5):  # 1 s of +1 m/s^2, drifting left at 0.3 m/s
        f = sim.step(EgoCommand(1.0, 0.3))
    assert f.speed[f.ego] == pytest.approx(v0 + 1.0, abs=0.05)
    assert f.xy[f.ego, 1] - y0 == pytest.approx(0.3, abs=0.06)
    f = sim.step(EgoCommand(-50.0, 0.0))  # clipped to the hardest braking allowed
    assert f.speed[f.ego] == pytest.approx(max(v0 + 1.0 - 8.0 * 0.2, 0), abs=0.05)
    sim.close()

    # A stopped ego: reactive traffic stops behind it; traffic that ignores it runs into it.
    def stop(_k: int) -> EgoCommand:
        return EgoCommand(-8.0, 0.0)

    hits = {}
    for reaction in ("reactive", "ignore"):
        s = short(duration=12.0, **{"ego.enabled": True, "ego.reaction": reaction, "ego.speed": 4.0})
        scene, _ = run(s, 2, stop)
        hits[reaction] = int(collision_matrix(scene.xy, scene.heading, scene.length, scene.width, scene.valid,
                                              rows=[scene.ego]).sum())
    assert hits["reactive"] == 0 and hits["ignore"] > 0, hits


def test_ego_braking_to_a_stop_while_edging_over_keeps_its_heading():
    """Sideways speed is bounded by the forward speed after the step: the body never turns past atan(vy_max / 4)."""
    spec = short(duration=6.0, **{"ego.enabled": True, "ego.insert_at": 0.0, "ego.speed": 3.0})
    sim = make_simulator(spec)
    f = sim.reset(1)
    headings, speeds = [], []
    for _ in range(8):  # hard braking from 3 m/s, asking for the fastest drift to the left throughout
        f = sim.step(EgoCommand(-2.5, 1.0))
        headings.append(float(f.heading[f.ego]))
        speeds.append(float(f.speed[f.ego]))
    sim.close()
    assert speeds[0] > 0.0 and speeds[-1] == 0.0, speeds  # it came to a stop inside the run
    assert max(np.abs(headings)) <= np.arctan(1.0 / 4.0) + 1e-6, np.degrees(headings)  # a car's vy_max is 1 m/s


def _cut_ins(scene: Scene, near: float = 20.0) -> int:
    """Background agents moving sideways into the ego's band within `near` m ahead of its front."""
    e = scene.ego
    dx = scene.xy[..., 0] - scene.xy[e, :, 0]
    band = np.abs(scene.xy[..., 1] - scene.xy[e, :, 1]) < 0.5 * (scene.width[:, None] + scene.width[e])
    gap = dx - 0.5 * (scene.length[:, None] + scene.length[e])
    ahead = scene.valid & scene.valid[e] & band & (gap > 0) & (gap < near)
    ahead[e] = False
    return int((ahead[:, 1:] & ~band[:, :-1] & scene.valid[:, :-1]).sum())


def test_cut_in_setting_cuts_in_front_of_the_ego():
    counts = {}
    for reaction in ("reactive", "cut_in"):
        spec = short(duration=20.0, **{"ego.enabled": True, "ego.reaction": reaction, "ego.speed": 7.0})
        counts[reaction] = sum(_cut_ins(run(spec, seed, lambda _k: EgoCommand(0.0, 0.0))[0]) for seed in (0, 1))
    assert counts["cut_in"] >= counts["reactive"] + 3, counts


def test_env_feels_like_highway_env():
    cfg = HeteroHighwayEnv.default_config()
    assert {"simulation_frequency", "policy_frequency", "screen_width", "demand", "crossing_rate"} <= set(cfg)
    env = HeteroHighwayEnv({"road_length": 150.0, "warmup": 5.0, "crossing_rate": 300.0})
    obs, info = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape and info["agents"] > 5
    obs, reward, terminated, truncated, info = env.step(None)
    vehicles = env.road.vehicles
    assert all(isinstance(v, HeteroAgent) for v in vehicles) and len(vehicles) == env.traffic.state.n
    v = vehicles[-1]  # the newest: it stays on the road for the next step
    assert type(v) is AGENT_CLASSES[AgentType(int(env.traffic.state.agent_type[-1]))]
    assert (v.LENGTH, v.WIDTH) == DEFAULT_FOOTPRINT[v.AGENT_TYPE]
    before = v.position.copy()
    env.step(None)
    assert v.alive and not np.array_equal(v.position, before)  # a live view of the simulation
    env.close()


def test_unsupported_layout_is_a_user_error():
    with pytest.raises(UserError, match="road.layout"):
        make_simulator(short(**{"road.layout": "intersection"}))
