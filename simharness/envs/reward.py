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

from simharness.envs.ttc import min_ttc
from simharness.metrics.separating_axis import gaps
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


def ego_safety(frame: Frame) -> EgoSafety:
    """Contact, min time-to-collision and min gap of the ego at `frame` (which must hold the ego)."""
    e = frame.ego
    xy = frame.xy.astype(np.float64)
    heading = frame.heading.astype(np.float64)
    length, width = frame.length.astype(np.float64), frame.width.astype(np.float64)
    rel = xy - xy[e]
    d = np.hypot(rel[:, 0], rel[:, 1])
    reach = 0.5 * np.hypot(length, width) + 0.5 * np.hypot(length[e], width[e]) + 1e-6
    ttc = _min_ttc(frame, xy, heading, length, width, rel, d, reach)
    # Gap: only agents whose lower bound d / sqrt(2) - reach can beat min(d) (an upper bound) or the cap.
    others = np.arange(len(d)) != e
    upper = min(float(d[others].min()) if others.any() else np.inf, GAP_CAP)
    rows = np.flatnonzero(others & (d / np.sqrt(2.0) - reach <= upper))
    gap = GAP_CAP
    if rows.size:
        gap = min(float(ego_gaps(xy, heading, length, width, e, rows).min()), GAP_CAP)
    return EgoSafety(ttc == 0.0, ttc, gap)


def ego_gaps(xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray, e: int,
             rows: np.ndarray) -> np.ndarray:
    """`safety.min_gap` of the ego (row e) to the agents `rows` (P,) at one frame: (P,) float32 m, the same
    floats, computed per axis component instead of through its (P, 4, 2) stacks and einsums (a tenth of
    the calls). xy (n, 2) m, heading (n,) rad, length, width (n,) m, all float64."""
    h = np.concatenate([heading, heading + np.pi / 2])  # the axes: each box's forward and left directions
    c, s = np.cos(h), np.sin(h)
    n = heading.size
    return gaps(xy[e] - xy[rows], c[:n], s[:n], c[n:], s[n:], length, width, e, rows)


def _min_ttc(frame: Frame, xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray,
             rel: np.ndarray, d: np.ndarray, reach: np.ndarray) -> float:
    """First sampled time (s) the ego's box overlaps another's under constant velocity; TTC_CAP if none."""
    e = frame.ego
    speed = frame.speed.astype(np.float64)
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    vel = speed[:, None] * np.stack([cos_h, sin_h], -1)
    return float(min_ttc(xy, rel, d, reach, vel, cos_h, sin_h, length, width, e, _TAUS, TTC_HORIZON, TTC_CAP))


def step_reward(weights: dict[str, float], moved: float, new_contact: bool, accel: float, prev_accel: float,
                lateral_speed: float, dt: float) -> float:
    """``progress * moved (m) + collision * new_contact + accel * a^2 + jerk * (da/dt)^2 + lateral * v_lat^2``."""
    return (weights["progress"] * moved + weights["collision"] * float(new_contact)
            + weights["accel"] * accel ** 2 + weights["jerk"] * ((accel - prev_accel) / dt) ** 2
            + weights["lateral"] * lateral_speed ** 2)
