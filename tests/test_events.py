"""Scripted [[events]]: schema and one-line errors, and the highway backend doing what each event says."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from simharness.errors import UserError
from simharness.scenario import SCENARIO_DIR, describe_schema, load_scenario, parse_scenario
from simharness.scene import AgentType
from simharness.sim import make_simulator

BASE = {
    "name": "ev", "backend": "highway", "duration": 8.0, "warmup": 3.0,
    "road": {"length": 300.0}, "demand": {"car": 300.0, "motorcycle": 300.0},
    "ego": {"enabled": True, "speed": 10.0},
}


def _spec(*events: dict):
    return parse_scenario({**BASE, "events": list(events)}, "test.toml")


def test_schema_lists_every_event_key_and_defaults():
    text = describe_schema()
    assert "[[events]]" in text
    for key in ("kind", "actor", "at", "ahead", "ahead_time", "side", "speed", "delay", "lead", "decel", "accel",
                "end_speed", "lateral_speed", "target"):
        assert f"events.{key} = " in text
    spec = _spec({"kind": "brake"})
    assert spec.events[0].decel == 6.0 and spec.events[0].actor == ""


@pytest.mark.parametrize("event, key", [
    ({"kind": "teleport"}, "events[0].kind"),
    ({"kind": "brake", "decel": 50.0}, "events[0].decel"),
    ({"kind": "brake", "actor": "spaceship"}, "events[0].actor"),
    ({"kind": "brake", "colour": "red"}, "events[0].colour"),
])
def test_bad_events_fail_with_one_line_naming_the_key(event, key):
    with pytest.raises(UserError) as e:
        _spec(event)
    assert key in str(e.value) and "\n" not in str(e.value)


def test_events_need_an_ego_and_a_list():
    with pytest.raises(UserError, match="ego.enabled"):
        parse_scenario({**BASE, "ego": {"enabled": False}, "events": [{"kind": "brake"}]}, "t.toml")
    with pytest.raises(UserError, match="list of tables"):
        parse_scenario({**BASE, "events": {"kind": "brake"}}, "t.toml")


def test_scenarios_without_events_keep_their_config_hash():
    spec = load_scenario("highway_mixed_dense")
    assert "events" not in spec.to_dict()
    assert spec.with_overrides({}).config_hash() == spec.config_hash()


def test_stress_suite_loads():
    names = sorted(p.stem for p in (SCENARIO_DIR / "stress").glob("*.toml"))
    assert len(names) >= 5
    for name in names:
        spec = load_scenario(f"stress/{name}")
        assert spec.events and spec.ego.enabled and spec.backend in ("highway", "sumo")


def _run(spec, seed: int = 3, frames: int | None = None):
    sim = make_simulator(spec)
    out = [sim.reset(seed)]
    for _ in range(frames or spec.num_frames - 1):
        out.append(sim.step(None))
    return sim, out


def _track(frames, agent_id):
    return np.array([[*f.xy[list(f.agent_id).index(agent_id)], f.speed[list(f.agent_id).index(agent_id)]]
                     if agent_id in f.agent_id else [np.nan] * 3 for f in frames])


def _new_actor(frames, agent_type: AgentType) -> str:
    before = set(frames[0].agent_id)
    for f in frames:
        for a, t in zip(f.agent_id, f.agent_type, strict=True):
            if a not in before and t == agent_type and a != "ego":
                return str(a)
    raise AssertionError(f"no {agent_type.label} placed")


def test_brake_places_a_lead_ahead_of_the_ego_and_stops_it():
    spec = _spec({"kind": "brake", "at": 1.0, "ahead": 5.0, "ahead_time": 1.0, "delay": 1.0, "decel": 6.0})
    _, frames = _run(spec)
    truck = _new_actor(frames, AgentType.TRUCK)
    tr = _track(frames, truck)
    k = int(np.flatnonzero(np.isfinite(tr[:, 0]))[0])
    assert frames[k].t == pytest.approx(1.2)  # the first recorded frame after `at`
    ego = _track(frames, "ego")
    # Placed ahead of the ego by ahead + ahead_time x speed (+ half lengths), in its band, at its speed.
    assert 5.0 + ego[k - 1, 2] < tr[k, 0] - ego[k, 0] < 5.0 + ego[k - 1, 2] + 14.0
    assert abs(tr[k, 1] - ego[k, 1]) < 0.3
    assert tr[k, 2] == pytest.approx(ego[k - 1, 2], abs=1.5)
    # Holds its speed for `delay`, then brakes at `decel` to a stop and stays there.
    assert abs(tr[k + 4, 2] - tr[k, 2]) < 0.1
    assert tr[-1, 2] == pytest.approx(0.0, abs=1e-6)
    dv = -np.diff(tr[k + 5:, 2]) / spec.dt
    assert dv.max() == pytest.approx(6.0, abs=0.1)


def test_step_out_pedestrian_crosses_the_carriageway_in_front_of_a_stopped_bus():
    spec = _spec({"kind": "step_out", "at": 1.0, "ahead": 0.0, "ahead_time": 2.0, "side": -1.0, "delay": 1.0,
                  "lateral_speed": 3.0})
    _, frames = _run(spec)
    ped, bus = _new_actor(frames, AgentType.PEDESTRIAN), _new_actor(frames, AgentType.BUS)
    p, b = _track(frames, ped), _track(frames, bus)
    k = int(np.flatnonzero(np.isfinite(p[:, 0]))[0])
    assert b[k:, 2].max() == 0.0 and b[k, 1] < -2.0  # the bus stands at the right kerb ...
    assert p[k, 0] > b[k, 0] + 6.0  # ... and the pedestrian in front of it
    assert p[k, 1] < -4.5 and p[-1, 1] > 5.0  # from the right kerb across to the far sidewalk
    vy = np.diff(p[k:, 1]) / spec.dt
    assert vy.max() == pytest.approx(3.0, abs=0.05)
    assert np.all(np.abs(np.diff(p[k:, 0])) < 1e-6)  # straight across


def test_cut_in_moves_into_the_ego_band_and_slows():
    spec = _spec({"kind": "cut_in", "at": 1.0, "ahead": 1.0, "ahead_time": 0.4, "side": 2.0, "delay": 0.8,
                  "lateral_speed": 2.0, "decel": 2.5, "end_speed": 5.0})
    _, frames = _run(spec)
    moto = _new_actor(frames, AgentType.MOTORCYCLE)
    m, e = _track(frames, moto), _track(frames, "ego")
    k = int(np.flatnonzero(np.isfinite(m[:, 0]))[0])
    assert m[k, 1] - e[k, 1] == pytest.approx(2.0, abs=0.4)
    goal = e[k + 4, 1]  # the ego's line when the manoeuvre starts (0.8 s after placement)
    assert m[-1, 1] == pytest.approx(goal, abs=0.35) and m[-1, 2] == pytest.approx(5.0, abs=1e-3)


def test_scripted_actors_follow_time_alone_so_a_branch_is_exact():
    """A deep copy stepped on its own reproduces the scripted actor's path (the oracle's premise)."""
    spec = load_scenario("stress/step_out").with_overrides({"duration": 8.0, "warmup": 3.0})
    sim = make_simulator(spec)
    sim.reset(1001)
    for _ in range(17):  # past the placement at 3 s
        sim.step(None)
    clone = copy.deepcopy(sim)
    a = [sim.step(None) for _ in range(15)]
    b = [clone.step(None) for _ in range(15)]
    for fa, fb in zip(a, b, strict=True):
        assert list(fa.agent_id) == list(fb.agent_id)
        np.testing.assert_array_equal(fa.xy, fb.xy)


def test_pull_out_of_a_two_wheeler_starts_at_the_kerb_and_swerves_onto_the_ego_line():
    spec = _spec({"kind": "pull_out", "actor": "motorcycle", "at": 1.0, "ahead": 0.0, "ahead_time": 0.5,
                  "side": -1.0, "speed": 4.0, "delay": 0.2, "accel": 2.0, "end_speed": 7.0,
                  "lateral_speed": 3.2})
    _, frames = _run(spec)
    moto = _new_actor(frames, AgentType.MOTORCYCLE)
    m, e = _track(frames, moto), _track(frames, "ego")
    k = int(np.flatnonzero(np.isfinite(m[:, 0]))[0])
    # Against the right kerb by its own width (not a bus's), ahead of the ego, at 4 m/s.
    assert m[k, 1] == pytest.approx(-(5.25 - 0.4 - 0.1), abs=0.35)
    assert m[k, 0] > e[k, 0] and m[k, 2] == pytest.approx(4.0, abs=0.5)
    vy = np.diff(m[k:, 1]) / spec.dt
    assert vy.max() == pytest.approx(3.2, abs=0.05)  # sideways at lateral_speed (under 0.8 x its speed)
    assert np.all(vy <= 0.8 * m[k:-1, 2] + 0.05)
    assert m[-1, 1] == pytest.approx(e[k + 1, 1], abs=1.0) and m[-1, 2] == pytest.approx(7.0, abs=1e-3)


def test_a_lead_places_the_actor_earlier_and_further_ahead_holding_it_until_its_manoeuvre():
    """With lead L the actor enters L s before `at`, L x (ego speed - its speed) further ahead, and still
    starts its manoeuvre `delay` s after `at`; without a lead it enters at `at`, as before."""
    event = {"kind": "pull_out", "actor": "motorcycle", "at": 3.0, "ahead": 0.0, "ahead_time": 0.5,
             "side": -1.0, "speed": 4.0, "delay": 0.4, "accel": 2.0, "end_speed": 7.0, "lateral_speed": 3.2}
    for lead in (0.0, 2.0):  # no background motorcycles: the first new one is the actor
        spec = parse_scenario({**BASE, "demand": {"car": 300.0}, "events": [{**event, "lead": lead}]}, "t.toml")
        _, frames = _run(spec)
        moto = _new_actor(frames, AgentType.MOTORCYCLE)
        m, e = _track(frames, moto), _track(frames, "ego")
        k = int(np.flatnonzero(np.isfinite(m[:, 0]))[0])
        t = np.array([f.t for f in frames])
        assert t[k] == pytest.approx(3.2 - lead)  # the first recorded frame after at - lead
        v = e[k - 1, 2]  # centre gap: half lengths + ahead_time x v + the lead's closing, less 0.2 s of closing
        assert m[k, 0] - e[k, 0] == pytest.approx(3.25 + 0.5 * v + (lead - 0.2) * (v - 4.0), abs=1.0)
        moves = np.flatnonzero(np.abs(np.diff(m[k:, 1])) > 1e-6)
        assert t[k + moves[0] + 1] == pytest.approx(3.6, abs=0.21)  # swerves delay s after `at`, lead or not
    assert spec.config_hash() != _spec(event).config_hash()
    assert "lead" not in _spec(event).to_dict()["events"][0]  # a lead-free event keeps its old hash


def test_a_lead_longer_than_at_is_refused_in_one_line():
    with pytest.raises(UserError, match=r"events\[0\].lead"):
        _spec({"kind": "brake", "at": 1.0, "lead": 2.0})
