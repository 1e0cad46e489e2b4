"""The composite closed-loop score and its parts: pure functions on small arrays, and score_episode on
hand-built scenes where the ego runs into a stopped car (its fault) or is run into while standing (not)."""

from __future__ import annotations

import numpy as np
import pytest

from simharness.closedloop import Issued, LoopConfig, aggregate, score_episode
from simharness.closedloop.scoring import (
    COMPOSITE_WEIGHTS,
    composite_score,
    flow_progress,
    off_drivable,
)
from simharness.scene import AgentType, Scene
from simharness.sim.base import RoadGeometry

ROAD = RoadGeometry(drivable=(np.array([[-100.0, -5.0], [300.0, -5.0], [300.0, 5.0], [-100.0, 5.0]]),))


def test_composite_gates_and_weights():
    w = sum(COMPOSITE_WEIGHTS.values())
    got = composite_score(at_fault_collided=np.array([0, 1, 0, 0, 0, 0]), left_drivable=np.array([0, 0, 1, 0, 0, 0]),
                          progress_ratio=np.array([1.0, 1.0, 1.0, 0.1, 0.5, np.nan]),
                          ttc_ok=np.array([1, 1, 1, 1, 1, 1]), comfortable=np.array([1, 1, 1, 1, 0, 1]))
    assert got.shape == (6,)
    assert got[0] == pytest.approx(1.0)
    assert got[1] == 0.0 and got[2] == 0.0  # at-fault collision, leaving the road: multiplicative zeros
    assert got[3] == 0.0  # less than a fifth of the flow's progress: no progress made
    assert got[4] == pytest.approx((COMPOSITE_WEIGHTS["progress"] * 0.5 + COMPOSITE_WEIGHTS["ttc"]) / w)
    assert np.isnan(got[5])
    # A near miss costs exactly the time-to-collision weight.
    assert composite_score(0, 0, 1.0, 0, 1) == pytest.approx(1 - COMPOSITE_WEIGHTS["ttc"] / w)


def test_flow_progress_uses_nearby_vehicles_only():
    t = 11
    x = np.arange(t) * 1.0  # the ego at 5 m/s (dt 0.2)
    xy = np.zeros((4, t, 2))
    xy[0, :, 0] = x
    xy[1, :, 0] = x + 10  # a car 10 m ahead at 10 m/s
    xy[2, :, 0] = x - 5  # a pedestrian: not traffic flow
    xy[3, :, 0] = x + 200  # a car far ahead
    speed = np.array([[5.0] * t, [10.0] * t, [1.0] * t, [30.0] * t])
    types = np.array([AgentType.CAR, AgentType.CAR, AgentType.PEDESTRIAN, AgentType.CAR], np.int8)
    valid = np.ones((4, t), bool)
    assert flow_progress(xy, speed, types, valid, 0, 0.2) == pytest.approx(10.0 * (t - 1) * 0.2)
    assert np.isnan(flow_progress(xy[[0, 2]], speed[[0, 2]], types[[0, 2]], valid[[0, 2]], 0, 0.2))


def test_off_drivable_flags_frames_outside_the_carriageway():
    xy = np.array([[0.0, 0.0], [0.0, 3.5], [0.0, 4.5], [0.0, 0.0]])
    valid = np.array([True, True, True, False])
    off = off_drivable(xy, np.zeros(4), 4.0, 2.0, valid, ROAD)
    # y = 3.5: the side at 4.5 (4.3 shrunk) is on; y = 4.5: off; an invalid frame never counts.
    assert off.tolist() == [False, False, True, False]
    assert not off_drivable(xy, np.zeros(4), 4.0, 2.0, valid, RoadGeometry()).any()


def _two_car_scene(ego_speed: float, other_speed: float, other_x0: float, t: int = 40,
                   queue_ahead: bool = False) -> Scene:
    """The ego from x = 0 and one other car from other_x0, both on y = 0, constant speeds, dt 0.2 s;
    queue_ahead: a third car stands 7 m ahead of the ego (a reason to stand)."""
    dt = 0.2
    time = np.arange(t) * dt
    n = 3 if queue_ahead else 2
    xy = np.zeros((n, t, 2), np.float32)
    xy[0, :, 0] = ego_speed * time
    xy[1, :, 0] = other_x0 + other_speed * time
    speed = np.array([[ego_speed] * t, [other_speed] * t, [0.0] * t][:n], np.float32)
    if queue_ahead:
        xy[2, :, 0] = 7.0
    return Scene(xy=xy, heading=np.zeros((n, t), np.float32), speed=speed, valid=np.ones((n, t), bool),
                 agent_id=np.array(["ego", "car", "queue"][:n]), agent_type=np.full(n, AgentType.CAR, np.int8),
                 length=np.full(n, 4.0, np.float32), width=np.full(n, 1.8, np.float32), dt=dt, ego=0,
                 meta={"road": ROAD.to_dict()})


def test_running_into_a_stopped_car_scores_zero_being_rear_ended_does_not():
    into = score_episode(_two_car_scene(10.0, 0.0, 40.0), Issued(), LoopConfig())
    assert into["collided"] == 1.0 and into["at_fault_collided"] == 1.0 and into["composite"] == 0.0
    # Standing in a queue and rear-ended: not the ego's fault (standing for nothing would be: phantom braking).
    hit = score_episode(_two_car_scene(0.0, 10.0, -40.0, queue_ahead=True), Issued(), LoopConfig())
    assert hit["collided"] == 1.0 and hit["at_fault_collided"] == 0.0
    # Standing still while a car moves near: progress ratio 0 -> no progress made -> 0, but not for the fault.
    assert hit["progress_ratio"] == 0.0 and hit["composite"] == 0.0
    free = score_episode(_two_car_scene(10.0, 10.0, 30.0), Issued(), LoopConfig())
    assert free["collided"] == 0.0 and free["left_drivable"] == 0.0 and free["progress_ratio"] == 1.0
    assert free["composite"] == pytest.approx(composite_score(0, 0, 1.0, free["ttc_ok"], free["comfortable"]))
    assert free["composite"] > 0.8


def test_scorecard_carries_the_composite_with_a_ci():
    eps = [score_episode(_two_car_scene(10.0, s, 30.0), Issued(), LoopConfig()) | {"seed": i, "realtime_factor": 1.0}
           for i, s in enumerate((10.0, 10.0, 0.0))]
    card = aggregate(eps)
    assert card["composite"]["n"] == 3
    assert card["composite"]["mean"] == pytest.approx(np.mean([e["composite"] for e in eps]))
    assert card["composite"]["lo"] <= card["composite"]["mean"] <= card["composite"]["hi"]


def test_comfort_is_judged_from_the_first_commanded_frame():
    # The simulator drives the ego's first frame: a jump in speed there (its hand-over) is not the planner's.
    scene = _two_car_scene(10.0, 10.0, 30.0)
    speed = scene.speed.copy()
    speed[0, 0] = 8.0  # 10 m/s^2 into the second frame, then constant
    handed = score_episode(scene.replace(speed=speed), Issued(), LoopConfig())
    assert handed["comfortable"] == 1.0
    # The same jump one frame later is the planner's doing.
    speed[0, :2] = 8.0
    later = score_episode(scene.replace(speed=speed), Issued(), LoopConfig())
    assert later["comfortable"] == 0.0 and later["accel_max"] > 4.05
