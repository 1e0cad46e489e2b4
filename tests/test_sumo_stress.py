"""SUMO stress scenarios on real libsumo: each loads, its scripted actors appear and do their manoeuvre,
and a fork of the worker (what the exact oracle branches) carries them on exactly.

Warm-up is shortened to keep each run a few seconds; the events are timed from the ego's start.
"""

from __future__ import annotations

import numpy as np
import pytest

from simharness.errors import UserError
from simharness.scenario import SCENARIO_DIR, load_scenario, parse_scenario
from simharness.scene import AgentType
from simharness.sim.base import EgoCommand, Frame
from simharness.sim.sumo.process import SumoProcess
from simharness.sim.sumo.simulator import SumoSimulator

SUMO_STRESS = sorted(p.stem for p in (SCENARIO_DIR / "stress").glob("sumo_*.toml"))


def _frames(name: str, seconds: float) -> list[Frame]:
    spec = load_scenario(f"stress/{name}").with_overrides({"warmup": 20.0, "duration": seconds})
    sim = SumoSimulator(spec)
    try:
        frames = [sim.reset(3)]
        frames += [sim.step(None) for _ in range(spec.num_frames - 1)]
    finally:
        sim.close()
    return frames


def _track(frames: list[Frame], agent: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t,) times, (t, 2) xy and (t,) heading of one agent over the frames it is in."""
    t, xy, hd = [], [], []
    for f in frames:
        i = np.flatnonzero(f.agent_id == agent)
        if i.size:
            t.append(f.t)
            xy.append(f.xy[i[0]])
            hd.append(f.heading[i[0]])
    return np.array(t), np.array(xy).reshape(-1, 2), np.array(hd)


def test_every_sumo_stress_scenario_loads_with_events():
    assert len(SUMO_STRESS) >= 3
    for name in SUMO_STRESS:
        spec = load_scenario(f"stress/{name}")
        assert spec.backend == "sumo" and spec.events and spec.ego.enabled


def test_pedestrian_runs_out_between_two_stopped_buses():
    frames = _frames("sumo_ped_between_buses", 6.0)
    spec = load_scenario("stress/sumo_ped_between_buses")
    event = spec.events[0]
    t, ped, _ = _track(frames, "ev0.0")
    _, bus_behind, _ = _track(frames, "ev0.1")
    _, bus_ahead, _ = _track(frames, "ev1.0")
    placed = event.at - event.lead
    assert t.size and abs(t[0] - (placed + 0.2)) < 0.11  # first recorded in the frame after its placement
    assert all(f.ego >= 0 for f in frames if f.t >= t[0])
    assert np.ptp(bus_behind, axis=0).max() < 1e-3 and np.ptp(bus_ahead, axis=0).max() < 1e-3  # they stand
    assert bus_behind[0, 0] < ped[0, 0] < bus_ahead[0, 0]  # the pedestrian between them (road runs +x)
    stands = int(round((event.lead + event.delay) * spec.record_hz)) - 1
    assert np.allclose(ped[:stands, 1], ped[0, 1]) and ped[stands + 2, 1] > ped[0, 1]  # stands until it runs ...
    assert abs(ped[0, 0] - ped[-1, 0]) < 1e-3 and ped[-1, 1] - ped[0, 1] > 3.0  # ... then runs across, leftwards


@pytest.mark.parametrize("name, actor", [("sumo_turn_across", AgentType.CAR),
                                         ("sumo_rickshaw_turn_across", AgentType.RICKSHAW)])
def test_oncoming_actor_turns_across_the_egos_path(name: str, actor: AgentType):
    frames = _frames(name, 7.0)
    t, car, heading = _track(frames, "ev0.0")
    assert t.size
    first = next(f for f in frames if abs(f.t - t[0]) < 1e-9)
    assert first.agent_type[np.flatnonzero(first.agent_id == "ev0.0")[0]] == actor
    e = frames[-1].ego
    ego_y = frames[-1].xy[e, 1]
    assert car[0, 1] > 0.0 > ego_y  # placed on the opposite carriageway
    assert abs(abs(heading[0]) - np.pi) < 0.05  # heading against the ego
    assert car[-1, 1] < ego_y + 1.0 and abs(heading[-1] + np.pi / 2) < 0.3  # turned across, heading south


def test_fork_of_the_worker_carries_the_script_on_exactly():
    spec = load_scenario("stress/sumo_turn_across").with_overrides({"warmup": 20.0, "duration": 8.0})
    live = SumoProcess(spec)
    try:
        live.reset(5)
        for _ in range(17):  # placed at 1.5 s (its lead); fork before the turn starts (4 s)
            live.step(None)
        branch = live.branch()
        try:
            cmds = [EgoCommand(-1.0, 0.0)] * 12
            a = [live.step(c) for c in cmds]
            b = [branch.step(c) for c in cmds]
        finally:
            branch.close()
    finally:
        live.close()
    for fa, fb in zip(a, b, strict=True):
        assert list(fa.agent_id) == list(fb.agent_id) and np.array_equal(fa.xy, fb.xy)
    i = np.flatnonzero(a[-1].agent_id == "ev0.0")
    assert i.size and abs(abs(a[-1].heading[i[0]]) - np.pi) > 0.2  # the actor is turning in both


def test_turn_across_is_for_the_sumo_backend_only():
    base = {"name": "x", "backend": "highway", "ego": {"enabled": True},
            "events": [{"kind": "turn_across"}]}
    with pytest.raises(UserError, match=r"events\[0\]\.kind") as e:
        parse_scenario(base, "t.toml")
    assert "\n" not in str(e.value)
