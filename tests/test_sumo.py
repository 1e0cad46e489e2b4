"""SUMO backend on real libsumo: determinism, density and heterogeneity, lateral spread, ego, errors.

libsumo holds one simulation per process: every test closes its simulator before the next starts.
"""

from __future__ import annotations

import numpy as np
import pytest

from simharness.closedloop.suite import stress_scenarios
from simharness.errors import SimulatorError
from simharness.metrics.collisions import box_heading
from simharness.metrics.safety import ego_contact
from simharness.scenario import load_scenario
from simharness.scene import AgentType, Scene
from simharness.sim.base import EgoCommand, scene_from_frames
from simharness.sim.sumo.ego import entry_speed
from simharness.sim.sumo.net import Carriageway
from simharness.sim.sumo.simulator import SumoSimulator


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


@pytest.mark.parametrize("reaction", ["reactive", "ignore"])
def test_ego_drifting_to_the_edge_and_braking_records_the_motion_it_made(reaction: str):
    """Sideways speed is bounded by the forward speed (no sliding once stopped, told to), and the heading and speed
    are the motion made: it eases into the carriageway's edge, then moves straight on and its heading says so."""
    spec = load_scenario("sumo_arterial_dense").with_overrides({
        "warmup": 20.0, "duration": 14.0, "ego.enabled": True, "ego.insert_at": 0.0, "ego.speed": 6.0,
        "ego.reaction": reaction})
    side: list[float] = []

    def command(k: int, now) -> EgoCommand:
        if now.ego >= 0 and not side:  # across to the far edge (8 m at 1 m/s), then back while braking to a stop
            side.append(-float(np.sign(now.extra["lateral_offset"][now.ego]) or 1.0))
        s = side[0] if side else 0.0
        return EgoCommand(0.0, s) if k < 50 else EgoCommand(-2.0, -s)

    scene = _record(spec, 0, command)
    e = scene.ego
    v = scene.valid[e]
    turn = np.abs(scene.heading[e] - scene.extra["sim_heading"][e])[v]
    lat = scene.extra["lateral_offset"][e][v]
    assert scene.speed[e][v][-1] == pytest.approx(0.0, abs=1e-6)  # it stopped
    assert turn.max() <= np.arctan(1.0 / 4.0) + 1e-3, np.degrees(turn.max())  # a car drifts at 1 m/s at most
    still = np.abs(np.diff(lat)) < 1e-6  # at the edge: no sideways motion made
    assert still.sum() >= 5 and turn[1:][still].max() < 1e-3
    assert np.abs(lat[49] - lat[1]) > 7.0 and turn[1:][~still].max() > 0.1  # moving across, the heading shows it
    arrive = int(np.argmax(still))  # the first frame at the edge: eased into it, not stopped dead from 1 m/s
    assert 0.0 < abs(lat[arrive] - lat[arrive - 1]) / spec.dt < 0.6


@pytest.mark.parametrize("reaction", ["reactive", "ignore"])
def test_ego_enters_at_a_speed_it_can_stop_from(reaction: str):
    """Placed 1.4 m behind a car at 4.5 m/s (stress/sumo_turn_across, seed 3010), the ego does not enter at the
    scenario's 10 m/s, from which no braking could avoid the car: braking at its hardest from its first frame, it
    touches no one (it entered at 10 m/s and ran into the car on both ego paths before)."""
    spec = stress_scenarios(["sumo_turn_across"])[0].with_overrides({"duration": 3.0, "ego.reaction": reaction})
    scene = _record(spec, 3010, lambda k, now: EgoCommand(-7.0, 0.0))
    e = scene.ego
    first = int(np.argmax(scene.valid[e]))
    contact = ego_contact(scene.xy, box_heading(scene), scene.length, scene.width, scene.valid, e)
    assert scene.speed[e, first] < 5.0
    assert not contact.any()


def test_entry_speed_is_cut_only_where_no_braking_could_stop_in_time():
    cw = Carriageway(edge="e", start=np.zeros(2), end=np.array([500.0, 0.0]), width=7.0, centre_offset=0.0)
    one = np.ones(1)

    def speed(gap: float, lead: float, lateral: float = 0.0) -> float:  # the agent's rear `gap` m ahead of the ego
        xy = np.array([[60.0 + 2.25 + gap + 2.25, -lateral]])
        return entry_speed(cw, 60.0, 0.0, xy, one * 4.5, one * 1.8, one * lead, 4.5, 1.8, 10.0, 0.2)

    assert speed(1.4, 4.5) == pytest.approx(4.5)  # 5.5 m/s faster than the car: 3.3 m to stop, 1.4 m there
    assert speed(8.0, 0.0) == pytest.approx((8.0 - 2.0) / 1.2)  # a stopped car 8 m ahead: what the gap can follow at
    assert speed(6.2, 3.8) == 10.0  # 4.0 m to stop, 6.2 m there: entering fast into dense traffic is the scenario
    assert speed(1.4, 12.0) == 10.0  # faster than the ego
    assert speed(1.4, 4.5, lateral=2.0) == 10.0  # beside the ego's band, not ahead in it


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


def _cut_ins(scene: Scene, near: float = 20.0) -> int:
    """Frames where a background vehicle moves sideways into the ego's band within `near` m ahead of it
    (the arterial runs along +x, so the band is in y)."""
    e = scene.ego
    band = np.abs(scene.xy[..., 1] - scene.xy[e, :, 1]) < 0.5 * (scene.width[:, None] + scene.width[e])
    gap = scene.xy[..., 0] - scene.xy[e, :, 0] - 0.5 * (scene.length[:, None] + scene.length[e])
    ahead = scene.valid & scene.valid[e] & band & (gap > 0) & (gap < near)
    ahead[e] = False
    return int((ahead[:, 1:] & ~band[:, :-1] & scene.valid[:, :-1]).sum())


def test_cut_in_reaction_cuts_in_front_of_the_ego():
    counts, hits = {}, {}
    for reaction in ("reactive", "cut_in"):
        spec = load_scenario("sumo_arterial_dense").with_overrides({
            "warmup": 20.0, "duration": 20.0, "ego.enabled": True, "ego.insert_at": 0.0, "ego.speed": 6.0,
            "ego.reaction": reaction})
        scenes = [_record(spec, seed, lambda _k, _f: EgoCommand(0.0, 0.0)) for seed in (1, 2)]
        counts[reaction] = sum(_cut_ins(s) for s in scenes)
        hits[reaction] = sum(e["kind"] == "collision" and "ego" in (e["agent_id"], e["other_id"])
                             for s in scenes for e in s.meta["events"])
    assert counts["cut_in"] >= counts["reactive"] + 4, counts
    assert hits == {"reactive": 0, "cut_in": 0}  # cutting in, not running into the ego


def test_unrecorded_stepping_is_the_same_simulation():
    """`advance_unrecorded` (the bench's raw stepping) does the simulation work of `step`, no less."""
    spec = load_scenario("sumo_intersection_dense").with_overrides({"warmup": 30.0, "duration": 12.0})
    sim = SumoSimulator(spec)
    sim.reset(1)
    sim.advance_unrecorded(40)
    raw = sim.step()
    sim.close()
    recorded = _record(spec.with_overrides({"duration": 8.4}), 1)
    k = recorded.num_frames - 1
    v = recorded.valid[:, k]
    assert raw.t == pytest.approx(k * spec.dt)
    order = np.argsort(raw.agent_id)
    rows = np.flatnonzero(v)[np.argsort(recorded.agent_id[v])]
    assert np.array_equal(raw.agent_id[order], recorded.agent_id[rows])
    assert np.array_equal(raw.xy[order], recorded.xy[rows, k])
    assert any(a.startswith("xped") for a in raw.agent_id)  # crossing pedestrians took part


def test_intersection_left_turns_wait_at_the_stop_line_and_nobody_collides():
    spec = load_scenario("sumo_intersection_dense").with_overrides({"duration": 60.0})
    sim = SumoSimulator(spec)
    net = sim.net.net_file.read_text()
    assert net.count('contPos="0.00"') == 4  # the four left turns: no waiting point inside the junction
    scene = _record(spec, 0)
    kinds = [e["detail"].split()[1] for e in scene.meta["events"] if e["kind"] == "collision"]
    assert not [k for k in kinds if "pedestrian" not in k], kinds  # vehicle-vehicle
    assert not [k for k in kinds if k.count("pedestrian") == 2], kinds  # crossers keep apart
    assert not [e for e in scene.meta["events"] if e["kind"] == "teleport"]
    assert (scene.agent_type == AgentType.PEDESTRIAN).sum() >= 3
