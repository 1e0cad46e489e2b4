"""Ego planners: turn the current Scene and a forecast of the others into an `EgoCommand`.

- `SamplingPlanner`: prediction-aware. Candidates = constant longitudinal accelerations x target
  lateral offsets, rolled out over the forecast horizon with the ego's kinematic limits, scored on
  conflict with the forecast boxes (widened by the forecast's sigma), headway to agents ahead,
  progress, comfort and consistency with the previous plan. Vectorised over candidates x agents x time.
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

from simharness.scene import Forecast, Scene
from simharness.sim.base import EgoCommand, RoadGeometry


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
    max_decel: float = 7.0
    max_lateral_speed: float = 1.5
    max_slip: float = 0.3  # rad: lateral speed at most tan(max_slip) x forward speed (no sideways crabbing)


@dataclasses.dataclass(frozen=True)
class SamplingConfig:
    """Candidate sets and cost weights of the sampling planner (defaults tuned on the dense arterial)."""

    accelerations: tuple[float, ...] = (-7.0, -4.5, -2.5, -1.0, 0.0, 1.0, 2.5)  # m/s^2, clipped to limits
    lateral_offsets: tuple[float, ...] = (-3.0, -1.5, -0.6, 0.0, 0.6, 1.5, 3.0)  # m, + left
    horizon_s: float = 4.0  # seconds of the forecast used (shorter if the forecast is)
    margin_long: float = 0.8  # m added ahead and behind the boxes
    margin_lat: float = 0.3  # m added beside the boxes
    sigma_scale: float = 1.0  # boxes widened by this many forecast sigmas ...
    sigma_cap: float = 2.0  # ... but never by more than this (m)
    headway_s: float = 1.0  # desired time gap to agents ahead in the ego's band
    standstill_gap: float = 2.0  # m kept to a stopped leader
    behind_weight: float = 0.1  # conflicts caused by agents now behind the ego count this much
    w_collision: float = 1000.0
    w_headway: float = 2.0
    w_speed: float = 1.0
    w_accel: float = 0.05
    w_jerk: float = 0.02
    w_lateral: float = 0.05
    w_consistency: float = 0.2
    discount: float = 0.9  # per second: earlier conflicts weigh more


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
    def _axis(self, now: Scene) -> tuple[np.ndarray, float, float]:
        """Ego position (2,), road-axis heading (rad) and speed (m/s) at the last column."""
        e = now.ego
        h = float(now.heading[e, -1])
        v = float(now.speed[e, -1])
        if "sim_heading" in now.extra:  # backend's own body heading: aligned with the road, not the motion
            h = float(now.extra["sim_heading"][e, -1])
        else:
            h -= float(np.arctan2(self._prev_lat, max(v, 1e-3)))
        return now.xy[e, -1].astype(np.float64), h, v

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
        p0, h0, v0 = self._axis(now)
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
        """(C,) conflict + headway cost of every candidate against the forecast agents.

        Boxes are compared in each candidate's own frame: the other box's extent projected on the ego's
        axes (a conservative axis-aligned bound), both widened by margins and the forecast's sigma.
        """
        cfg, e = self.config, now.ego
        le, we = float(now.length[e]), float(now.width[e])
        rows = rows_of(now.agent_id, forecast.agent_id)
        keep = (rows >= 0) & (rows != e)
        axy = forecast.mean[keep, :frames].astype(np.float32)  # (M, F, 2)
        rows = rows[keep]
        fwd = np.array([np.cos(h0), np.sin(h0)], np.float32)
        # Prune agents that stay far ahead of or behind every candidate over the whole horizon.
        along0 = (axy - p0.astype(np.float32)) @ fwd  # (M, F)
        ex0 = (exy - p0) @ fwd  # (C, F)
        reach = 15.0 + cfg.standstill_gap + cfg.headway_s * float(ev.max())
        near = ((along0 > ex0.min(0) - reach) & (along0 < ex0.max(0) + reach)).any(1)
        axy, rows = axy[near], rows[near]
        if rows.size == 0:
            return np.zeros(exy.shape[0])
        sig_keep = np.flatnonzero(keep)[near]
        ah = _path_heading(now.xy[rows, -1], now.heading[rows, -1], axy).astype(np.float32)  # (M, F)
        widen = np.zeros(axy.shape[:2], np.float32)
        if forecast.sigma_rho is not None:
            widen = np.minimum(cfg.sigma_scale * forecast.sigma_rho[sig_keep, :frames, :2].max(-1), cfg.sigma_cap)
        ce, se = np.cos(eh).astype(np.float32)[:, None], np.sin(eh).astype(np.float32)[:, None]  # (C, 1, F)
        ca, sa = np.cos(ah)[None], np.sin(ah)[None]  # (1, M, F)
        ex32 = exy.astype(np.float32)
        rx = axy[None, ..., 0] - ex32[:, None, :, 0]  # (C, M, F)
        ry = axy[None, ..., 1] - ex32[:, None, :, 1]
        along = rx * ce + ry * se
        lat = ry * ce - rx * se
        cos_dh = np.abs(ca * ce + sa * se)  # |cos(ah - eh)| without trig on (C, M, F)
        sin_dh = np.abs(sa * ce - ca * se)
        la, wa = (now.length[rows] / 2)[None, :, None], (now.width[rows] / 2)[None, :, None]
        gap_along = np.abs(along) - (le / 2 + cfg.margin_long) - cos_dh * la - sin_dh * wa - widen[None]
        gap_lat = np.abs(lat) - (we / 2 + cfg.margin_lat) - sin_dh * la - cos_dh * wa - widen[None]
        # Agents now behind the ego (rear-enders) weigh less: their forecast ignores our braking.
        behind = (now.xy[rows, -1] - p0) @ fwd < -le / 2
        w_agent = np.where(behind, cfg.behind_weight, 1.0).astype(np.float32)  # (M,)
        in_band = gap_lat < 0
        conflict = (gap_along < 0) & in_band  # (C, M, F)
        cost = cfg.w_collision * np.einsum("cmf,m,f->c", conflict.astype(np.float32), w_agent,
                                           disc.astype(np.float32)) / frames
        # Headway: agents ahead inside the ego's lateral band, closer than the desired gap.
        want = (cfg.standstill_gap + cfg.headway_s * ev[:, None, :]).astype(np.float32)
        short = np.where((along > 0) & in_band, np.maximum(want - (gap_along + cfg.margin_long), 0.0), 0.0)
        cost += cfg.w_headway * np.einsum("cmf,f->c", (short / np.maximum(want, 1.0)) ** 2,
                                          disc.astype(np.float32)) / frames
        return cost.astype(np.float64)

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
