"""Ego safety at one frame and the per-step reward.

Safety gives what `simharness.metrics.safety` gives over all agents (contact, time-to-collision
sampled every 0.1 s up to the horizon, separating-axis gap) but only tests the agents that can decide
the minimum, found by exact bounds on the centre distance: two boxes overlap only when their centres
are within the sum of their half-diagonals (`reach`), so a pair is tested at the sampled times that
fall in the interval where constant-velocity centres are that close; and a separating-axis gap lies
between d / sqrt(2) - reach and d (d the centre distance), so only agents whose lower bound can beat
the smallest upper bound are measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simharness.envs.observation import ego_offsets
from simharness.envs.ttc import ttc_and_gap
from simharness.sim.base import Frame

TTC_HORIZON = 3.0  # s
TTC_STEP = 0.1  # s between sampled times
TTC_CAP = 10.0  # s reported when no collision is foreseen
GAP_CAP = 100.0  # m reported when nobody is closer
_TAUS = np.arange(0.0, TTC_HORIZON + 1e-9, TTC_STEP)


@dataclass(frozen=True)
class EgoSafety:
    """contact: the ego's box overlaps another now; ttc (s, <= TTC_CAP); gap (m, <= GAP_CAP)."""

    contact: bool
    ttc: float
    gap: float


def ego_safety(frame: Frame, offsets: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> EgoSafety:
    """Contact, min time-to-collision and min gap of the ego at `frame` (which must hold the ego); `offsets`:
    `ego_offsets(frame)` if the caller has it already."""
    e = frame.ego
    xy, rel, d = ego_offsets(frame) if offsets is None else offsets
    length, width = frame.length.astype(np.float64), frame.width.astype(np.float64)
    half_diagonal = 0.5 * np.hypot(length, width)
    heading = frame.heading.astype(np.float64)
    h = np.concatenate([heading, heading + np.pi / 2])  # the axes: each box's forward and left directions
    c, s = np.cos(h), np.sin(h)
    n = heading.size
    ttc, gap = ttc_and_gap(xy, rel, d, half_diagonal, frame.speed, c[:n], s[:n], c[n:], s[n:], length, width, e,
                           _TAUS, TTC_HORIZON, TTC_CAP, GAP_CAP)
    return EgoSafety(ttc == 0.0, ttc, gap)


def step_reward(weights: dict[str, float], moved: float, new_contact: bool, accel: float, prev_accel: float,
                lateral_speed: float, dt: float) -> float:
    """``progress * moved (m) + collision * new_contact + accel * a^2 + jerk * (da/dt)^2 + lateral * v_lat^2``."""
    return (weights["progress"] * moved + weights["collision"] * float(new_contact)
            + weights["accel"] * accel ** 2 + weights["jerk"] * ((accel - prev_accel) / dt) ** 2
            + weights["lateral"] * lateral_speed ** 2)
