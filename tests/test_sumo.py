"""SUMO backend on real libsumo: determinism, density and heterogeneity, lateral spread, ego, errors.

libsumo holds one simulation per process: every test closes its simulator before the next starts.
"""

from __future__ import annotations

import numpy as np
import pytest

from simharness.errors import SimulatorError
from simharness.scenario import load_scenario
from simharness.scene import AgentType, Scene
from simharness.sim.base import EgoCommand, scene_from_frames
from simharness.sim.sumo import SumoSimulator


def _record(spec, seed: int, commands=None) -> Scene:
    sim = SumoSimulator(spec)
    try:
        frames = [sim.reset(seed)]
        for k in range(spec.num_frames - 1):
            frames.append(sim.step(commands(k, frames[-1]) if commands else None))
    finally:
        sim.close()
    return scene_from_frames(frames, spec.dt)


@pytest.fixture(scope="module")
def dense() -> Scene:
    spec = load_scenario("sumo_arterial_dense").with_overrides({"duration": 20.0})
    return _record(spec, 0)


def test_same_seed_same_frames_other_seed_differs():
    spec = load_scenario("sumo_arterial_dense").with_overrides({"warmup": 20.0, "duration": 6.0})
    a, b, c = _record(spec, 3), _record(spec, 3), _record(spec, 4)
    assert a.num_agents > 10
    assert a.equals(b) and a.meta["events"] == b.meta["events"]
    assert not a.equals(c)


def test_dense_meets_density_and_heterogeneity_targets(dense: Scene):
    spec = load_scenario("sumo_arterial_dense")
    within, per_frame, types = [], [], []
    for k in range(dense.num_frames):
        v = dense.valid[:, k]
        xy = dense.xy[v, k]
        d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
        within.append(((d < 50.0).sum(1) - 1).mean())
        per_frame.append(v.sum())
        types.append(np.unique(dense.agent_type[v]).size)
    assert np.mean(within) >= 15.0
    assert np.mean(per_frame) / (spec.road.length / 1000.0) >= 100.0
    assert min(types) >= 5
    # Moving traffic, not gridlock: vehicles keep a fair mean speed.
    veh = dense.valid & (dense.agent_type[:, None] != AgentType.PEDESTRIAN)
    assert dense.speed[veh].mean() > 3.0
    # Recorded positions lie on the road; SUMO's own boxes (centre, sim_heading) rarely touch.
    assert np.all(np.abs(dense.xy[..., 1][dense.valid]) <= spec.road.width / 2 + 0.5)
    assert set(dense.extra) == {"sim_heading", "lateral_offset"}


def test_small_types_spread_over_the_width(dense: Scene):
    half = load_scenario("sumo_arterial_dense").road.width / 2
    for t in (AgentType.MOTORCYCLE, AgentType.SCOOTER):
        lat = dense.extra["lateral_offset"][(dense.agent_type[:, None] == t) & dense.valid]
        assert lat.size > 200
        assert np.percentile(lat, 95) - np.percentile(lat, 5) > 0.6 * 2 * half
        # Not a few lane centres: most 0.5 m bins across the width are used.
        hist, _ = np.histogram(lat, bins=np.arange(-half, half + 0.5, 0.5))
        assert (hist > 0).mean() > 0.8


def test_pedestrians_cross_and_walk(dense: Scene):
    peds = dense.agent_type == AgentType.PEDESTRIAN
    assert peds.any()
    lat = dense.extra["lateral_offset"]
    crossers = [r for r in np.flatnonzero(peds) if dense.agent_id[r].startswith("xped")]
    assert crossers, "no crossing pedestrian in 20 s"
    moved = [np.ptp(lat[r][dense.valid[r]]) for r in crossers]
    assert max(moved) > 2.0  # walked sideways across the carriageway


@pytest.mark.parametrize("reaction", ["reactive", "ignore"])
def test_ego_follows_commands(reaction: str):
    spec = load_scenario("sumo_arterial_dense").with_overrides({
        "warmup": 20.0, "duration": 8.0, "ego.enabled": True, "ego.insert_at": 0.0, "ego.speed": 3.0,
        "ego.reaction": reaction})

    def command(k: int, now) -> EgoCommand:
        if k < 15:
            return EgoCommand(1.5, 0.0)
        side = np.sign(now.extra["lateral_offset"][now.ego]) or 1.0
        return EgoCommand(0.0, -0.8 * side)  # towards the centre line, away from the edge

    scene = _record(spec, 0, command)
    e = scene.ego
    assert e >= 0 and scene.agent_id[e] == "ego"
    v = scene.valid[e]
    assert v[2:].all()  # enters at once, stays
    speed, lat = scene.speed[e], scene.extra["lateral_offset"][e]
    assert speed[15] - speed[2] > 1.5 * 12 * spec.dt * 0.8  # accelerated as told
    moved = abs(lat[-1] - lat[16])
    assert moved > 0.8 * (spec.num_frames - 17) * spec.dt * 0.8 or abs(lat[-1]) < 0.3  # moved sideways as told
    turn = scene.heading[e, 20] - scene.extra["sim_heading"][e, 20]
    assert abs(turn) > 0.02  # heading follows the lateral motion


def test_second_simulator_in_one_process_is_a_clear_error():
    spec = load_scenario("sumo_arterial_sparse").with_overrides({"warmup": 1.0, "duration": 1.0})
    first, second = SumoSimulator(spec), SumoSimulator(spec)
    try:
        first.reset(0)
        with pytest.raises(SimulatorError, match="one simulation per process"):
            second.reset(1)
        first.step()  # the first one is still alive
    finally:
        first.close()
        second.close()


@pytest.mark.parametrize("net_text, said", [
    ("<net><edge id='broken'", "not valid XML"),
    ('<net version="1.20"><edge id="a" from="X" to="Y"><lane id="a_0" index="0" speed="10" length="10" '
     'shape="0,0 10,0"/></edge></net>', "Unknown from-node 'X'"),
])
def test_bad_sumo_input_is_a_clear_error(net_text: str, said: str):
    spec = load_scenario("sumo_arterial_sparse").with_overrides({"warmup": 1.0, "duration": 1.0})
    sim = SumoSimulator(spec)
    sim.net.net_file.write_text(net_text)  # an impossible network
    with pytest.raises(SimulatorError, match=r"sumo_arterial_sparse, seed 0: .*" + said):
        sim.reset(0)
    with pytest.raises(SimulatorError, match="not running"):
        sim.step()
    sim.close()
    # The process can still run a simulation afterwards.
    ok = SumoSimulator(spec)
    assert ok.reset(0).num_agents >= 0
    ok.close()


def test_road_geometry_matches_recorded_positions(dense: Scene):
    spec = load_scenario("sumo_arterial_dense")
    sim = SumoSimulator(spec)  # geometry is built without starting SUMO
    inside = sim.road.on_road(dense.xy[dense.valid & (dense.agent_type[:, None] != AgentType.PEDESTRIAN)])
    assert inside.mean() > 0.99
    assert len(sim.road.sidewalks) == 2
