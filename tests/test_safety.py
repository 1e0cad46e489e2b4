"""Safety and comfort metrics on hand-placed boxes: rotated, touching, apart, approaching."""

from __future__ import annotations

import numpy as np
import pytest

from simharness.metrics import comfort, safety
from simharness.scene import AgentType


def _pair(b_xy, b_heading=0.0, b_len=4.0, b_wid=2.0):
    """Ego (row 0) 4 x 2 m at the origin heading +x, agent (row 1) as given; one frame."""
    xy = np.array([[[0.0, 0.0]], [b_xy]], np.float64)
    heading = np.array([[0.0], [b_heading]])
    length, width = np.array([4.0, b_len]), np.array([2.0, b_wid])
    return xy, heading, length, width, np.ones((2, 1), bool)


@pytest.mark.parametrize("b_xy, b_heading, touching, gap", [
    ((4.0, 0.0), 0.0, True, 0.0),              # nose to tail, edges touching
    ((4.5, 0.0), 0.0, False, 0.5),             # 0.5 m apart
    ((0.0, 2.3), 0.0, False, 0.3),             # side by side, 0.3 m apart
    ((3.2, 0.0), np.pi / 2, False, 0.2),        # rotated 90 deg: spans x 2.2..4.2
    ((2.9, 0.0), np.pi / 2, True, 0.0),         # rotated 90 deg, overlapping
    ((3.6, 0.0), np.pi / 4, False, None),       # rotated 45 deg: corner 3.6-2.12 = 1.48 > 2? no
])
def test_contact_and_gap_on_hand_placed_boxes(b_xy, b_heading, touching, gap):
    xy, heading, length, width, valid = _pair(b_xy, b_heading)
    contact = safety.ego_contact(xy, heading, length, width, valid, ego=0)
    g = safety.min_gap(xy, heading, length, width, valid, ego=0)
    if b_heading == np.pi / 4:
        # Corner of a 4 x 2 box rotated 45 deg reaches 3.6 - (2 + 1) / sqrt(2) = 1.48 < 2: overlap.
        assert contact[1, 0] and g[1, 0] == 0
        return
    assert contact[1, 0] == touching
    assert not contact[0, 0]  # the ego never collides with itself
    assert g[1, 0] == pytest.approx(gap, abs=1e-5)
    assert np.isinf(g[0, 0])


def test_gap_is_a_lower_bound_corner_to_corner():
    # Diagonal offset: true corner distance sqrt(0.5^2 + 0.5^2) = 0.71; separating-axis bound gives 0.5.
    xy, heading, length, width, valid = _pair((4.5, 2.5))
    g = safety.min_gap(xy, heading, length, width, valid, ego=0)[1, 0]
    assert 0.5 - 1e-5 <= g <= np.hypot(0.5, 0.5)


def test_ttc_constant_velocity_boxes():
    # Ego at 10 m/s towards a stopped 4 m box 20 m ahead: the 16 m gap closes in 1.6 s.
    n, t = 4, 1
    xy = np.array([[[0, 0]], [[20, 0]], [[0, 3]], [[20, -20]]], np.float64)
    vel = np.array([[[10, 0]], [[0, 0]], [[-10, 0]], [[0, 10]]], np.float64)
    heading = np.array([[0.0], [0.0], [np.pi], [np.pi / 2]])
    length, width = np.full(n, 4.0), np.full(n, 2.0)
    ttc = safety.time_to_collision(xy, vel, heading, length, width, np.ones((n, t), bool), ego=0, horizon=5.0)
    assert ttc[1, 0] == pytest.approx(1.6, abs=0.1 + 1e-6)
    assert np.isinf(ttc[2, 0])  # beside, moving away
    # Crossing at right angles: boxes first touch when the ego front reaches the agent's side, ~1.7 s.
    assert 1.5 <= ttc[3, 0] <= 2.0
    assert np.isinf(ttc[0, 0])
    # Overlapping now -> 0.
    xy2 = xy.copy()
    xy2[1, 0] = [3.0, 0.5]
    ttc2 = safety.time_to_collision(xy2, vel, heading, length, width, np.ones((n, t), bool), ego=0)
    assert ttc2[1, 0] == 0.0


def test_ttc_rotated_agent_misses_when_it_passes_first():
    # A crossing agent that clears the ego's path before the ego arrives: no collision in the horizon.
    xy = np.array([[[0, 0]], [[20, -2]]], np.float64)
    vel = np.array([[[5, 0]], [[0, 10]]], np.float64)
    heading = np.array([[0.0], [np.pi / 2]])
    ttc = safety.time_to_collision(xy, vel, heading, np.full(2, 4.0), np.full(2, 2.0), np.ones((2, 1), bool),
                                   ego=0)
    assert np.isinf(ttc[1, 0])


def test_near_misses_exclude_spells_that_end_in_contact():
    ttc = np.array([[np.inf] * 6,
                    [3, 1.0, 0.8, 2, 1.2, np.inf],       # two close spells, no contact: 2 near misses
                    [1.0, 0.5, 0.0, 0.0, np.inf, np.inf]])  # close spell ending in contact: a collision
    contact = np.zeros((3, 6), bool)
    contact[2, 2:4] = True
    nm = safety.near_misses(ttc, contact, np.ones((3, 6), bool), threshold=1.5)
    assert nm.sum() == 2 and nm[1, 1] and nm[1, 4]
    assert not nm[2].any()


def test_ttc_relevant_leaves_out_agents_behind_and_a_standing_ego():
    # Ego (row 0) at the origin heading +x; agents ahead, beside, behind-left (bearing 135 deg), dead behind.
    xy = np.array([[0, 0], [10, 0], [0, 3], [-3, 3], [-10, 0]], float)[:, None].repeat(2, 1)
    heading = np.zeros((5, 2))
    speed = np.array([[5.0, 0.0]] + [[3.0, 3.0]] * 4)  # the ego moves at frame 0, stands at frame 1
    rel = safety.ttc_relevant(xy, heading, speed, np.ones((5, 2), bool), ego=0)
    assert rel[:, 0].tolist() == [False, True, True, True, False]
    assert not rel[:, 1].any()


def test_collisions_by_type_count_spells():
    contact = np.zeros((3, 8), bool)
    contact[1, 1:3] = True
    contact[1, 5] = True  # second spell with the same bus
    contact[2, 4:8] = True
    by_type = safety.collisions_by_type(contact, np.array([0, AgentType.BUS, AgentType.MOTORCYCLE], np.int8))
    assert by_type["bus"] == 2 and by_type["motorcycle"] == 1 and by_type["car"] == 0
    assert set(by_type) == {t.label for t in AgentType}


def test_background_collisions_leave_out_the_ego():
    # Rows: 0 ego overlapping 1; 2 and 3 overlap each other; one frame.
    xy = np.array([[[0, 0]], [[3, 0]], [[50, 0]], [[53, 0.5]]], np.float64)
    heading = np.zeros((4, 1))
    ev = safety.background_collisions(xy, heading, np.full(4, 4.0), np.full(4, 2.0), np.ones((4, 1), bool), ego=0)
    assert ev.tolist() == [[0, 2, 3]]


def test_comfort_and_progress():
    dt = 0.2
    t = np.arange(26) * dt
    speed = 2.0 + 1.0 * t  # constant 1 m/s^2
    valid = np.ones(26, bool)
    acc, ok = comfort.longitudinal_acceleration(speed, valid, dt)
    assert np.allclose(acc[ok], 1.0, atol=1e-5) and not ok[0]
    jk, jok = comfort.jerk(speed, valid, dt)
    assert np.allclose(jk[jok], 0.0, atol=1e-4) and jok.sum() == 24
    x = 2.0 * t + 0.5 * t**2
    heading = np.full(26, np.pi / 6)
    xy = np.stack([x * np.cos(np.pi / 6), x * np.sin(np.pi / 6)], -1)
    assert comfort.progress(xy, heading, valid) == pytest.approx(x[-1], rel=1e-5)
    # A gap in validity drops the steps across it.
    valid[10] = False
    assert comfort.progress(xy, heading, valid) == pytest.approx(x[-1] - (x[11] - x[9]), rel=1e-5)
    stopped = np.array([0.0, 0.2, 3.0, 0.1, 5.0])
    assert comfort.time_stuck(stopped, np.ones(5, bool), dt) == pytest.approx(0.6)
    summary = comfort.comfort_summary(speed, heading, np.ones(26, bool), dt)
    assert summary["accel_max"] == pytest.approx(1.0, abs=1e-4) and summary["lat_accel_max"] == 0.0


def test_at_fault_rule_on_three_contacts():
    # Ego (row 0) at the origin heading +x; one frame; every other agent touching it.
    xy = np.array([[[0, 0]], [[4.0, 0]], [[-4.0, 0]], [[0.5, 1.9]]], np.float64)
    vel = np.array([[[8, 0]], [[0, 0]], [[12, 0]], [[8, -1.5]]], np.float64)  # stopped ahead, fast behind, cut-in
    onsets = np.ones((4, 1), bool)
    onsets[0] = False
    heading = np.arctan2(vel[..., 1], vel[..., 0])
    fault = safety.ego_at_fault(onsets, xy, vel, heading, np.full(4, 1.8), np.ones((4, 1), bool), ego=0)
    assert fault[1, 0]  # ran into a stopped agent ahead
    assert not fault[2, 0]  # rear-ended
    assert not fault[3, 0]  # cut into from the side while holding its line
    assert not fault[0, 0]
    # The ego swerving left into a car holding its line beside it: the ego's fault.
    xy2 = np.array([[[0, 0]], [[0.5, 1.7]], [[20, 0]], [[20, 3]]], np.float64)
    vel2 = np.array([[[8, 1.5]], [[8, 0]], [[8, 0]], [[8, 0]]], np.float64)
    fault2 = safety.ego_at_fault(onsets, xy2, vel2, np.arctan2(vel2[..., 1], vel2[..., 0]), np.full(4, 1.8),
                                 np.ones((4, 1), bool), ego=0)
    assert fault2[1, 0]


def _queue(ego_speed: np.ndarray, leader_gap: float | None) -> tuple:
    """Ego (row 0) on +x with the given speed profile (T,), a follower 8 m behind at 8 m/s, an optional
    stopped leader `leader_gap` m ahead (centre to centre); frames 0.2 s apart."""
    t = ego_speed.size
    x = np.concatenate([[0.0], np.cumsum(ego_speed[1:] * 0.2)])
    rows = [np.stack([x, 0 * x], -1), np.stack([-8.0 + 8.0 * 0.2 * np.arange(t), np.zeros(t)], -1)]
    speed = [ego_speed, np.full(t, 8.0)]
    if leader_gap is not None:
        rows.append(np.stack([np.full(t, leader_gap), np.zeros(t)], -1))
        speed.append(np.zeros(t))
    n = len(rows)
    return (np.stack(rows), np.stack(speed), np.zeros((n, t)), np.full(n, 4.0), np.full(n, 1.8),
            np.ones((n, t), bool))


def test_phantom_braking_and_rear_end_fault():
    brake = np.array([8.0, 8.0, 8.0, 6.0, 4.0, 2.0, 0.0, 0.0, 0.0, 0.0])
    for leader, expect in ((None, True), (12.0, False)):
        xy, speed, heading, length, width, valid = _queue(brake, leader)
        phantom = safety.phantom_braking(xy, speed, heading, length, width, valid, ego=0, dt=0.2)
        assert phantom[6:].any() == expect, leader  # braked then stood, with (not) a stopped car ahead
        assert not phantom[:3].any()  # cruising
        onsets = np.zeros(valid.shape, bool)
        onsets[1, 7] = True  # the follower hits the ego from behind at frame 7
        vel = np.stack([speed, np.zeros_like(speed)], -1)
        fault = safety.ego_at_fault(onsets, xy, vel, heading, width, valid, 0, phantom=phantom)
        assert fault[1, 7] == expect


def test_walked_into_from_the_side_at_the_rear_is_not_the_egos_fault():
    # The ego brakes and stands with nothing ahead (phantom braking); a pedestrian walking across at 1.4 m/s
    # reaches its rear quarter: 0.23 m into the ego's band at the contact, 0.05 m clear of its side the frame
    # before (half widths 0.9 + 0.25 m).
    brake = np.array([8.0, 8.0, 8.0, 6.0, 4.0, 2.0, 0.0, 0.0, 0.0, 0.0])
    xy, speed, heading, length, width, valid = _queue(brake, None)
    stop_x = xy[0, -1, 0]
    xy[1] = np.stack([np.full(10, stop_x - 1.5), 0.92 + 1.4 * 0.2 * (7 - np.arange(10))], -1)
    speed[1], width[1], length[1] = 1.4, 0.5, 0.5
    heading[1] = -np.pi / 2 - 0.1  # a little against the flow: not counted in its direction
    phantom = safety.phantom_braking(xy, speed, heading, length, width, valid, ego=0, dt=0.2)
    assert phantom[7]
    onsets = np.zeros(valid.shape, bool)
    onsets[1, 7] = True
    vel = np.stack([speed * np.cos(heading), speed * np.sin(heading)], -1)
    lat = xy[1, :, 1] - xy[0, :, 1]
    assert abs(lat[7]) < 1.15 - 0.1 <= abs(lat[6])  # in the band at the contact, beside the ego before
    assert not safety.ego_at_fault(onsets, xy, vel, heading, width, valid, 0, phantom=phantom)[1, 7]
    # The same pedestrian already in the ego's band the frame before: hit from behind, in line, for nothing.
    xy[1, 6, 1] = xy[1, 7, 1]
    assert safety.ego_at_fault(onsets, xy, vel, heading, width, valid, 0, phantom=phantom)[1, 7]
