"""Ego safety at one frame, what the ego did over one step, and the per-step reward.

Reward per step (weights ``config["reward"]``, defaults in `simharness.envs.config.DEFAULT_CONFIG`):

    collision-free:  on_road * (alive + progress * min(max(moved / (target_speed * dt), 0), 1)
                                + accel * min((a / 4.05)^2, 1) + jerk * min((j / 8.37)^2, 1)
                                + lateral * min((v_lat / max_lateral_speed)^2, 1)
                                + ttc * max(1 - ttc_now / 3 s, 0))
    a new contact:   collision_at_fault (or collision_hit) * steps * span,
                     span = alive + progress + |accel| + |jerk| + |lateral| + |ttc|

a, j and v_lat are what the ego did (its measured acceleration, jerk and speed across the traffic flow),
not what it was told; ttc_now is its min time-to-collision (`ego_safety`, constant velocities over 3 s), so
closing in on someone costs before the contact does; the bounds are the scorecard's comfort bounds
(nuPlan's). A contact is judged as the scorecard judges it (`ego_fault`): at fault (ran into someone, cut
across into them, braked or stood for nothing and was hit) or hit. A collision-free step earns between
alive - |comfort and ttc weights| and alive + progress, so ``steps * span`` exceeds the spread between any
two episodes' returns: with collision_at_fault <= -1 any collision-free episode outscores any episode with an
at-fault collision, whatever the other weights (signs as documented).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from simharness.envs.observation import ego_offsets
from simharness.envs.ttc import ttc_and_gap
from simharness.metrics import collisions, safety
from simharness.scene import AgentType, heading_velocity
from simharness.sim.base import Frame, RoadGeometry, scene_from_frames

TTC_HORIZON = 3.0  # s
TTC_STEP = 0.1  # s between sampled times
TTC_CAP = 10.0  # s reported when no collision is foreseen
GAP_CAP = 100.0  # m reported when nobody is closer
_TAUS = np.arange(0.0, TTC_HORIZON + 1e-9, TTC_STEP)
ACCEL_BOUND = 4.05  # m/s^2: the scorecard's comfort bounds (nuPlan's), where the comfort terms saturate
JERK_BOUND = 8.37  # m/s^3
DRIVABLE_TOLERANCE = 0.2  # m: the ego's box is shrunk by this before the drivable test (as the scorecard's)
FAULT_FRAMES = 9  # frames kept for the fault judgement: the scorecard's 1.5 s phantom-braking window at 5 Hz, + 1


@dataclass(frozen=True)
class EgoSafety:
    """contact: the ego's box overlaps another now; ttc (s, <= TTC_CAP); gap (m, <= GAP_CAP)."""

    contact: bool
    ttc: float
    gap: float


def ego_safety(frame: Frame, offsets: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> EgoSafety:
    """Contact, min time-to-collision and min gap of the ego at `frame` (which must hold the ego), the boxes
    turned as the scorecard's (`box_heading`); `offsets`: `ego_offsets(frame)` if the caller has it already."""
    e = frame.ego
    xy, rel, d = ego_offsets(frame) if offsets is None else offsets
    length, width = frame.length.astype(np.float64), frame.width.astype(np.float64)
    half_diagonal = 0.5 * np.hypot(length, width)
    heading = box_heading(frame).astype(np.float64)
    h = np.concatenate([heading, heading + np.pi / 2])  # the axes: each box's forward and left directions
    c, s = np.cos(h), np.sin(h)
    n = heading.size
    ttc, gap = ttc_and_gap(xy, rel, d, half_diagonal, frame.speed, c[:n], s[:n], c[n:], s[n:], length, width, e,
                           _TAUS, TTC_HORIZON, TTC_CAP, GAP_CAP)
    return EgoSafety(ttc == 0.0, ttc, gap)


def box_heading(frame: Frame) -> np.ndarray:
    """(n,) rad: the simulator's body headings (``extra["sim_heading"]``, SUMO) where it has them, else the
    frame's: the headings the scorecard's collision boxes use (`collisions.box_heading`)."""
    return frame.extra.get("sim_heading", frame.heading)


@dataclass(frozen=True)
class Motion:
    """What the ego did over one step: moved (m made good along its heading at the start), accel (m/s^2,
    measured speed change), jerk (m/s^3), lateral (m/s, speed across the local traffic flow)."""

    moved: float
    accel: float
    jerk: float
    lateral: float


def ego_motion(prev: Frame, frame: Frame, near: np.ndarray, dt: float, prev_accel: float) -> Motion:
    """The ego's `Motion` from `prev` to `frame` (both hold the ego); near (k,): rows of `frame`'s observed
    neighbours, whose vehicles moving the ego's way give the flow direction (the ego's heading if none)."""
    (x, y), (px, py) = frame.xy[frame.ego].tolist(), prev.xy[prev.ego].tolist()
    h = float(prev.heading[prev.ego])
    ch, sh = math.cos(h), math.sin(h)
    dx, dy = x - px, y - py
    moved = dx * ch + dy * sh
    hd = frame.heading[near].astype(np.float64)
    fx, fy = np.cos(hd), np.sin(hd)
    keep = (fx * ch + fy * sh > 0) & (frame.agent_type[near] != int(AgentType.PEDESTRIAN))
    ax, ay = (float(fx[keep].sum()), float(fy[keep].sum())) if keep.any() else (ch, sh)
    norm = max(math.hypot(ax, ay), 1e-9)
    lateral = (dy * ax - dx * ay) / norm / dt  # displacement across the flow axis
    accel = (float(frame.speed[frame.ego]) - float(prev.speed[prev.ego])) / dt
    return Motion(float(moved), accel, (accel - prev_accel) / dt, float(lateral))


def ego_on_road(frame: Frame, road: RoadGeometry | None) -> bool:
    """Whether every corner of the ego's box (shrunk by DRIVABLE_TOLERANCE) is on the drivable area, as the
    scorecard's `left_drivable` tests it; True for a road without drivable polygons."""
    if road is None or not road.drivable:
        return True
    e = frame.ego
    h = float(box_heading(frame)[e])
    hl = max(float(frame.length[e]) / 2 - DRIVABLE_TOLERANCE, 0.0)
    hw = max(float(frame.width[e]) / 2 - DRIVABLE_TOLERANCE, 0.0)
    (x, y), c, s = frame.xy[e].tolist(), math.cos(h), math.sin(h)  # scalars: the box's four corners by hand
    corners = np.array([[x + c * a - s * b, y + s * a + c * b] for a, b in ((hl, hw), (hl, -hw), (-hl, -hw),
                                                                             (-hl, hw))])
    return bool(road.on_road(corners).all())


def ego_fault(frames: Sequence[Frame], dt: float) -> bool:
    """Whether the ego caused the contact that starts at the last of `frames` (the last FAULT_FRAMES, the ego
    in the last), judged by the scorecard's own rule (`safety.ego_at_fault` with phantom braking)."""
    scene = scene_from_frames(frames, dt)
    e = scene.ego
    xy, hd, ln, wd, va = scene.xy, scene.heading, scene.length, scene.width, scene.valid
    bh = collisions.box_heading(scene)
    contact = safety.ego_contact(xy, bh, ln, wd, va, e)
    onsets = np.zeros_like(contact)
    onsets[:, -1] = contact[:, -1] & ~contact[:, -2] if contact.shape[1] > 1 else contact[:, -1]
    if not onsets.any():  # the env's test saw a contact the scene's does not start here: judge those in contact
        onsets[:, -1] = contact[:, -1]
    vel = heading_velocity(scene.speed, hd)
    phantom = safety.phantom_braking(xy, scene.speed, bh, ln, wd, va, e, dt)
    return bool(safety.ego_at_fault(onsets, xy, vel, hd, wd, va, e, phantom=phantom)[:, -1].any())


def step_reward(weights: dict[str, float], motion: Motion, target_step: float, max_lateral_speed: float,
                on_road: bool, collision: str | None, steps: int, ttc: float = TTC_CAP) -> float:
    """The reward of one step (module docstring). target_step (m): target_speed * dt; collision: None,
    "at_fault" or "hit" (a new contact this step); steps: steps per episode; ttc (s): the ego's min
    time-to-collision now (`ego_safety`)."""
    w = weights
    if collision is not None:  # more than the widest spread of returns between episodes of `steps` steps
        span = (w["alive"] + w["progress"] + abs(w["accel"]) + abs(w["jerk"]) + abs(w["lateral"])
                + abs(w["ttc"]))
        return w["collision_" + collision] * steps * span
    if not on_road:
        return 0.0
    speed = min(max(motion.moved / target_step, 0.0), 1.0)
    return (w["alive"] + w["progress"] * speed + w["accel"] * min((motion.accel / ACCEL_BOUND) ** 2, 1.0)
            + w["jerk"] * min((motion.jerk / JERK_BOUND) ** 2, 1.0)
            + w["lateral"] * min((motion.lateral / max_lateral_speed) ** 2, 1.0)
            + w["ttc"] * max(1.0 - ttc / TTC_HORIZON, 0.0))
