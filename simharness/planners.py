"""Ego planners: turn the current Scene and a forecast of the others into an `EgoCommand`.

- `SamplingPlanner`: prediction-aware. Candidates = constant longitudinal accelerations x target
  lateral offsets, rolled out over the forecast horizon with the ego's kinematic limits, scored on
  collision probability with the forecast's Gaussians (discounted over time), rear-end risk from
  followers that could not stop behind a sudden stop, headway to agents ahead, progress, comfort and
  consistency with the previous plan. Vectorised over candidates x agents x time; the per-pair terms in one
  compiled pass (`_pair_terms`, numba: numpy's floats to the bit, ~3x faster than the broadcast arrays).
  Fed TraPHic, constant-velocity or true ("oracle") futures it brackets a predictor between a floor
  and a ceiling (see `simharness.closedloop`).
- `BackgroundPlanner`: returns None, so the simulator's own background model drives the ego
  (the "none" reference: no prediction at all).
- `ConstantSpeedPlanner`: blind, holds speed and lateral position (a test reference).

Ego frame used below: x along the road axis at the ego (its heading without the lateral motion
the planner itself commanded), y to the left.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol, runtime_checkable

import numpy as np
from numba import njit, types
from scipy.special import ndtr

from simharness.scene import Forecast, Scene
from simharness.sim.base import EGO_MAX_DECEL, EgoCommand, RoadGeometry


@runtime_checkable
class Planner(Protocol):
    """plan(now, forecast): `now` holds recent frames (column -1 is now, `now.ego` the ego row);
    `forecast` the others' futures (or None). Returns the command for the next frame, or None to let
    the simulator's own model drive the ego."""

    def plan(self, now: Scene, forecast: Forecast | None) -> EgoCommand | None: ...


@dataclasses.dataclass(frozen=True)
class EgoLimits:
    """Kinematic limits of the ego (m/s, m/s^2)."""

    max_speed: float = 13.9
    max_accel: float = 2.5
    max_decel: float = EGO_MAX_DECEL
    max_lateral_speed: float = 1.5
    max_slip: float = 0.3  # rad: lateral speed at most tan(max_slip) x forward speed (no sideways crabbing)


@dataclasses.dataclass(frozen=True)
class SamplingConfig:
    """Candidate sets and cost weights of the sampling planner (tuned on seeds 100-105 of the dense
    arterial under cut_in, never on the scored seeds 0-19)."""

    accelerations: tuple[float, ...] = (-7.0, -4.5, -2.5, -1.0, 0.0, 1.0, 2.5)  # m/s^2, clipped to limits
    lateral_offsets: tuple[float, ...] = (-3.0, -1.5, -0.6, 0.0, 0.6, 1.5, 3.0)  # m, + left
    horizon_s: float = 4.0  # seconds of the forecast used (shorter if the forecast is)
    margin_long: float = 0.5  # m added ahead and behind the boxes
    margin_lat: float = 0.2  # m added beside the boxes
    sigma_floor: float = 0.2  # m: position sigma assumed on top of the forecast's own (deterministic ones too) ...
    sigma_growth: float = 0.1  # ... growing by this many m per second ahead
    headway_s: float = 1.0  # desired time gap to agents ahead in the ego's band
    standstill_gap: float = 2.0  # m kept to a stopped leader
    follower_reaction_s: float = 0.8  # a follower holds its speed this long before braking ...
    follower_decel: float = 3.5  # ... at this rate (m/s^2): faster stops than it can follow are rear-end risks
    w_collision: float = 300.0  # x expected overlaps per step, discounted mean over the horizon
    w_rear: float = 30.0  # x (discounted) share of steps a follower could not stop behind the ego
    w_headway: float = 2.0
    w_speed: float = 4.0  # x mean squared shortfall from the speed limit (standing: 4)
    w_accel: float = 0.05
    w_jerk: float = 0.02
    w_lateral: float = 0.05
    w_consistency: float = 0.2
    discount: float = 0.5  # per second: later steps weigh less (forecasts and our own plan drift)


class SamplingPlanner:
    """Prediction-aware sampling planner; see the module docstring.

    limits: ego kinematics; config: candidates and weights; road: drivable area (candidates whose
    box would leave it are discarded); dt: seconds per frame of the rollout (the forecast's dt).
    """

    def __init__(self, limits: EgoLimits | None = None, config: SamplingConfig | None = None,
                 road: RoadGeometry | None = None) -> None:
        self.limits = limits or EgoLimits()
        self.config = config or SamplingConfig()
        self.set_road(road)
        acc = np.clip(np.asarray(self.config.accelerations, np.float64), -self.limits.max_decel, self.limits.max_accel)
        a, d = np.meshgrid(np.unique(acc), np.asarray(self.config.lateral_offsets, np.float64), indexing="ij")
        self._acc, self._off = a.ravel(), d.ravel()  # (C,)
        self.reset()

    def set_road(self, road: RoadGeometry | None) -> None:
        """Drivable area the candidates must stay on (None: unconstrained)."""
        self.road = road if road is not None and road.drivable else None

    def reset(self) -> None:
        """Forget the previous plan (start of an episode)."""
        self._prev_acc = 0.0
        self._prev_lat = 0.0
        self.last_cost: np.ndarray | None = None  # (C,) for inspection
        self.last_rollout: np.ndarray | None = None  # (F, 2) chosen ego path, world frame

    # ------------------------------------------------------------------ rollout
    def rollout(self, p0: np.ndarray, h0: float, v0: float, dt: float, frames: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every candidate's future: xy (C, F, 2) world m, heading (C, F), speed (C, F), lateral speed (C,)."""
        lim = self.limits
        t = (np.arange(frames) + 1) * dt  # (F,)
        v = np.clip(v0 + self._acc[:, None] * t[None], 0.0, max(lim.max_speed, v0))  # (C, F)
        v_prev = np.concatenate([np.full((v.shape[0], 1), v0), v[:, :-1]], 1)
        x = np.cumsum(0.5 * (v + v_prev) * dt, 1)
        # Lateral: towards the offset as fast as allowed (limit and slip angle at the current speed), then hold.
        rate = np.minimum(lim.max_lateral_speed, np.tan(lim.max_slip) * np.minimum(v_prev, v))  # (C, F) m/s
        y_abs = np.minimum(np.abs(self._off)[:, None], np.cumsum(rate * dt, 1))
        y = np.sign(self._off)[:, None] * y_abs
        dy = np.diff(y, axis=1, prepend=0.0)
        vlat = dy[:, 0] / dt  # (C,) first command
        moving = np.abs(dy) > 1e-9
        fwd, left = np.array([np.cos(h0), np.sin(h0)]), np.array([-np.sin(h0), np.cos(h0)])
        xy = p0 + x[..., None] * fwd + y[..., None] * left
        heading = h0 + np.where(moving, np.arctan2(dy / dt, np.maximum(v, 1e-3)), 0.0)
        return xy, heading, v, vlat

    # ------------------------------------------------------------------ scoring
    def plan(self, now: Scene, forecast: Forecast | None) -> EgoCommand:
        """Best candidate's first command; see the module docstring for the cost."""
        cfg, lim = self.config, self.limits
        e = now.ego
        if e < 0:
            raise ValueError("SamplingPlanner.plan needs a Scene with its ego row set")
        dt = forecast.dt if forecast is not None else now.dt
        frames = max(1, int(round(cfg.horizon_s / dt)))
        if forecast is not None:
            frames = min(frames, forecast.horizon)
        p0, h0, v0 = ego_axis(now, self._prev_lat)
        exy, eh, ev, vlat = self.rollout(p0, h0, v0, dt, frames)  # (C, F, 2), (C, F), (C, F), (C,)
        c = exy.shape[0]
        t = (np.arange(frames) + 1) * dt
        disc = cfg.discount ** t  # (F,)
        we = float(now.width[e])

        cost = np.zeros(c)
        if forecast is not None and len(forecast.agent_id):
            cost += self._interaction_cost(now, forecast, p0, h0, exy, eh, ev, frames, disc)
        # Progress: track the speed limit.
        cost += cfg.w_speed * np.mean(((ev - lim.max_speed) / max(lim.max_speed, 1.0)) ** 2, 1)
        cost += cfg.w_accel * self._acc**2 + cfg.w_jerk * ((self._acc - self._prev_acc) / max(dt, 1e-3)) ** 2 / 25
        cost += cfg.w_lateral * np.abs(self._off)
        cost += cfg.w_consistency * ((self._acc - self._prev_acc) ** 2 / 4 + (vlat - self._prev_lat) ** 2)
        if self.road is not None:
            cost[~self._on_road(exy, eh, we)] = np.inf
        if not np.isfinite(cost).any():  # nowhere on the road: brake straight
            cost = np.where(self._off == 0, -self._acc, np.inf)
        best = int(np.argmin(cost))
        self.last_cost, self.last_rollout = cost, exy[best]
        self._prev_acc, self._prev_lat = float(self._acc[best]), float(vlat[best])
        return EgoCommand(acceleration=float(self._acc[best]), lateral_velocity=float(vlat[best]))

    def _interaction_cost(self, now: Scene, forecast: Forecast, p0: np.ndarray, h0: float, exy: np.ndarray,
                          eh: np.ndarray, ev: np.ndarray, frames: int, disc: np.ndarray) -> np.ndarray:
        """(C,) collision-risk + rear-end + headway cost of every candidate against the forecast agents.

        Collision probability of candidate c with agent m at step f: the forecast's bivariate Gaussian
        (world sigma_x, sigma_y, rho, plus a floor growing with time) rotated into the candidate's frame,
        integrated over the Minkowski sum of the two boxes (the other box projected on the ego's axes,
        a conservative axis-aligned bound), the two axes taken as independent. Risk = discounted mean
        over the steps of the summed probabilities. Followers (now behind, in the ego's band) are left to
        the rear-end term: their forecasts cannot know that they will brake for us, but how hard they can is
        known; agents behind but beside the ego still count (moving over into them is a side-swipe).
        """
        cfg, e = self.config, now.ego
        le, we = float(now.length[e]), float(now.width[e])
        rows = rows_of(now.agent_id, forecast.agent_id)
        keep = (rows >= 0) & (rows != e)
        axy = forecast.mean[keep, :frames].astype(np.float64)  # (M, F, 2)
        rows = rows[keep]
        fwd = np.array([np.cos(h0), np.sin(h0)])
        # Prune agents that stay far ahead of or behind every candidate over the whole horizon.
        along0 = (axy - p0) @ fwd  # (M, F)
        ex0 = (exy - p0) @ fwd  # (C, F)
        reach = 15.0 + cfg.standstill_gap + cfg.headway_s * float(ev.max())
        near = ((along0 > ex0.min(0) - reach) & (along0 < ex0.max(0) + reach)).any(1)
        axy, rows = axy[near], rows[near]
        if rows.size == 0:
            return np.zeros(exy.shape[0])
        sig_rows = np.flatnonzero(keep)[near]
        t = (np.arange(frames) + 1) * forecast.dt
        floor2 = ((cfg.sigma_floor + cfg.sigma_growth * t) ** 2)[None]  # (1, F)
        if forecast.sigma_rho is not None:
            sr = forecast.sigma_rho[sig_rows, :frames].astype(np.float64)
            sxx, syy, sxy = sr[..., 0] ** 2 + floor2, sr[..., 1] ** 2 + floor2, sr[..., 2] * sr[..., 0] * sr[..., 1]
        else:  # the same covariance for every agent: the sigmas below are computed once per (candidate, step)
            sxx = syy = floor2
            sxy = np.zeros_like(floor2)
        ah = _path_heading(now.xy[rows, -1], now.heading[rows, -1], axy)  # (M, F)
        ce, se = np.cos(eh), np.sin(eh)  # (C, F)
        # Marginal sigmas of the world covariance on the candidate's axes: (C, M, F), or (C, 1, F) without sigmas.
        cx, sx = ce[:, None], se[:, None]
        s_along = np.sqrt(cx * cx * sxx[None] + 2 * cx * sx * sxy[None] + sx * sx * syy[None])
        s_lat = np.sqrt(sx * sx * sxx[None] - 2 * cx * sx * sxy[None] + cx * cx * syy[None])
        # Followers (behind, in our band now) are left to the rear-end term; those behind beside us still count.
        behind = (now.xy[rows, -1] - p0) @ fwd < -le / 2  # (M,)
        lat_now = (now.xy[rows, -1] - p0) @ np.array([-fwd[1], fwd[0]])
        follow = behind & (np.abs(lat_now) < (now.width[rows] + we) / 2)
        want = cfg.standstill_gap + cfg.headway_s * ev  # (C, F) m: desired gap to an agent ahead
        live, a1, b1, a2, b2, short2 = _pair_terms(
            exy, ce, se, axy, np.cos(ah), np.sin(ah), (now.length[rows] / 2).astype(np.float64),
            (now.width[rows] / 2).astype(np.float64), le / 2 + cfg.margin_long, we / 2 + cfg.margin_lat,
            s_along, s_lat, ~follow, want, cfg.margin_long)
        # The normal CDFs (scipy's) where neither factor is exactly 0; the product is 0.0 everywhere else.
        prob = np.zeros(short2.size)
        prob[live] = (ndtr(a1) - ndtr(b1)) * (ndtr(a2) - ndtr(b2))
        prob = prob.reshape(short2.shape)  # (C, M, F)
        # Expected overlaps, not capped at 1: a candidate already touching one agent must still avoid the next.
        cost = cfg.w_collision * (prob.sum(1) * disc[None]).sum(1) / disc.sum()
        # Rear-end: followers now behind in the ego's band hold speed for the reaction time, then brake.
        if follow.any():
            vf = now.speed[rows[follow], -1].astype(np.float64)[:, None]  # (B, 1)
            x0 = ((now.xy[rows[follow], -1] - p0) @ fwd)[:, None]
            tb = np.minimum(np.maximum(t - cfg.follower_reaction_s, 0.0)[None], vf / cfg.follower_decel)  # braking s
            x_f = x0 + vf * np.minimum(t, cfg.follower_reaction_s)[None] + vf * tb - 0.5 * cfg.follower_decel * tb**2
            gap = ex0[:, None] - x_f[None] - le / 2 - (now.length[rows[follow]] / 2)[None, :, None]  # (C, B, F)
            cost += cfg.w_rear * ((gap < 0).any(1) * disc[None]).sum(1) / disc.sum()
        # Headway: agents ahead inside the ego's lateral band, closer than the desired gap (short2, from the kernel).
        cost += cfg.w_headway * np.einsum("cmf,f->c", short2, disc) / frames
        return cost

    def _on_road(self, exy: np.ndarray, eh: np.ndarray, width: float) -> np.ndarray:
        """(C,) whether both sides of the ego stay on the drivable area at every rollout frame."""
        side = np.stack([-np.sin(eh), np.cos(eh)], -1) * (width / 2)  # (C, F, 2)
        pts = np.stack([exy + side, exy - side], 2)  # (C, F, 2 sides, 2)
        return self.road.on_road(pts).all(axis=(1, 2))


class BackgroundPlanner:
    """The "none" reference: no prediction, the simulator's own background model drives the ego."""

    def plan(self, now: Scene, forecast: Forecast | None) -> None:
        return None


class ConstantSpeedPlanner:
    """Blind: holds speed and lateral position whatever happens (a floor for tests)."""

    def plan(self, now: Scene, forecast: Forecast | None) -> EgoCommand:
        return EgoCommand(0.0, 0.0)


# ndtr(x) is exactly 1.0 for every x >= _NDTR_ONE and exactly 0.0 for every x <= _NDTR_ZERO (1 - 2^-54 rounds to 1;
# erfc underflows), so a difference of two such values is exactly 0 there (checked in tests/test_planners.py).
_NDTR_ONE, _NDTR_ZERO = 8.3, -38.0


# Compiled (or loaded from numba's cache) on import, so that the SUMO oracle's forked branches inherit it rather
# than each loading it again at its first call.
_F1, _F2, _F3 = types.float64[:], types.float64[:, :], types.float64[:, :, :]


@njit((_F3, _F2, _F2, _F3, _F2, _F2, _F1, _F1, types.float64, types.float64, _F3, _F3, types.boolean[:], _F2,
       types.float64), cache=True)
def _pair_terms(exy: np.ndarray, ce: np.ndarray, se: np.ndarray, axy: np.ndarray, ca: np.ndarray, sa: np.ndarray,
                la: np.ndarray, wa: np.ndarray, along0: float, lat0: float, s_along: np.ndarray, s_lat: np.ndarray,
                counted: np.ndarray, want: np.ndarray, margin_long: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every (candidate c, agent m, step f) pair of `SamplingPlanner._interaction_cost` in one pass, compiled: the
    same float64 operations in the same order as numpy's broadcast evaluation, so the same floats to the bit.

    exy (C, F, 2) candidate centres, ce, se (C, F) cosine and sine of their headings; axy (M, F, 2) agent centres,
    ca, sa (M, F) of theirs; la, wa (M,) their half length and width; along0, lat0: the ego's half length and width
    plus the margins; s_along, s_lat (C, M or 1, F) sigmas on the candidate's axes; counted (M,): not a follower;
    want (C, F) m: desired gap ahead. In the box |along| < half_along, |lat| < half_lat (the other's footprint
    projected on the candidate's axes) the other's centre has a probability whose four normal-CDF arguments are
    returned where neither factor is exactly 0 (`_NDTR_ONE`, `_NDTR_ZERO`): live (K,) flat indices into (C, M, F),
    a1, b1, a2, b2 (K,). short2 (C, M, F): the squared headway shortfall of agents ahead inside the band, else 0.
    """
    n_c, n_f = ce.shape
    n_m = axy.shape[0]
    per_agent = s_along.shape[1] > 1
    live = np.empty(n_c * n_m * n_f, np.int64)
    a1, b1, a2, b2 = np.empty(live.size), np.empty(live.size), np.empty(live.size), np.empty(live.size)
    short2 = np.zeros((n_c, n_m, n_f))
    k = 0
    for c in range(n_c):
        for m in range(n_m):
            j = m if per_agent else 0
            for f in range(n_f):
                rx, ry = axy[m, f, 0] - exy[c, f, 0], axy[m, f, 1] - exy[c, f, 1]
                along, lat = rx * ce[c, f] + ry * se[c, f], ry * ce[c, f] - rx * se[c, f]
                cos_dh = abs(ca[m, f] * ce[c, f] + sa[m, f] * se[c, f])  # |cos(ah - eh)|
                sin_dh = abs(sa[m, f] * ce[c, f] - ca[m, f] * se[c, f])
                half_along = along0 + cos_dh * la[m] + sin_dh * wa[m]
                half_lat = lat0 + sin_dh * la[m] + cos_dh * wa[m]
                p1, q1 = (half_along - along) / s_along[c, j, f], (-half_along - along) / s_along[c, j, f]
                p2, q2 = (half_lat - lat) / s_lat[c, j, f], (-half_lat - lat) / s_lat[c, j, f]
                if q1 < _NDTR_ONE and p1 > _NDTR_ZERO and q2 < _NDTR_ONE and p2 > _NDTR_ZERO and counted[m]:
                    live[k], a1[k], b1[k], a2[k], b2[k] = (c * n_m + m) * n_f + f, p1, q1, p2, q2
                    k += 1
                if along > 0 and abs(lat) < half_lat:
                    w = want[c, f]
                    short = max(w - ((abs(along) - half_along) + margin_long), 0.0) / max(w, 1.0)
                    short2[c, m, f] = short * short
    return live[:k], a1[:k], b1[:k], a2[:k], b2[:k], short2


def ego_axis(now: Scene, lateral_speed: float) -> tuple[np.ndarray, float, float]:
    """The ego's position (2,) m, road-axis heading (rad) and speed (m/s) at the last column of `now`.

    The road axis is the backend's own body heading (`sim_heading`) where it records one, else the heading of
    motion less the lateral speed (m/s) the planner itself last commanded.
    """
    e = now.ego
    v = float(now.speed[e, -1])
    if "sim_heading" in now.extra:  # backend's own body heading: aligned with the road, not the motion
        h = float(now.extra["sim_heading"][e, -1])
    else:
        h = float(now.heading[e, -1]) - float(np.arctan2(lateral_speed, max(v, 1e-3)))
    return now.xy[e, -1].astype(np.float64), h, v


def rows_of(ids: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Row of each wanted id in ids, -1 where absent: ids (N,), wanted (M,) -> (M,) int."""
    if len(ids) == 0:
        return np.full(len(wanted), -1)
    order = np.argsort(ids)
    rows = order[np.clip(np.searchsorted(ids, wanted, sorter=order), 0, len(ids) - 1)]
    return np.where(ids[rows] == wanted, rows, -1)


def _path_heading(xy0: np.ndarray, h0: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Heading along forecast paths, current heading where the agent barely moves.

    xy0 (M, 2), h0 (M,), path (M, F, 2) -> (M, F) rad.
    """
    prev = np.concatenate([xy0[:, None].astype(np.float64), path[:, :-1]], 1)
    step = path - prev
    moving = np.hypot(step[..., 0], step[..., 1]) > 0.05
    return np.where(moving, np.arctan2(step[..., 1], step[..., 0]), h0[:, None])
