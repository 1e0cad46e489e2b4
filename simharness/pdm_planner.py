"""The default ego planner of the closed loop: proposals rolled out against the forecasts and scored by the
episode's own terms (nuPlan's PDM-Closed, Dauner et al. 2023, adapted to a lane-less road).

Every frame:
1. The others' futures over the planning horizon: every agent of `now` within `radius` m of the ego (its current
   observed state, always); an agent the forecast covers follows the forecast (padded at its last velocity where the
   forecast is shorter), any other agent (one the predictor dropped, or that appeared after the forecast was made)
   is extrapolated at constant velocity from its observed speed and heading. No agent vanishes from the plan because
   a forecast left it out.
2. Proposals: target speeds x lateral offsets. Longitudinally each follows the intelligent driver model (IDM) at its
   target speed behind the nearest agent ahead in its own corridor at each step, or entering it within
   `leader_lookahead_s` (a pedestrian forecast to cross the road: `pedestrian_lookahead_s`, long enough to stop for
   it comfortably) ahead of where the ego will be (the agents at their forecast positions), its acceleration
   moved towards IDM's at a bounded jerk and held within comfortable bounds (the emergency proposals may brake at the
   ego's limit); laterally each moves from the ego's reference line (the line
   the last chosen proposal was heading for) to its offset at a bounded lateral acceleration. Lane-less road: the
   offsets are metres, not lanes.
3. Scores, the episode's own terms: gates (the proposal collides with an agent it would be at fault for, or leaves
   the drivable area: 0) times a weighted mean of progress (over the best safe proposal's), time-to-collision (never
   under `ttc_threshold` against the agents' forecast motion, extrapolated at constant velocity as the scorecard
   does) and comfort (nuPlan's bounds), nuPlan's weights 5, 5, 2; ties go to the proposal nearest the last one.
   Where nothing on the road is clear, a proposal off it (the shoulder, the kerb) that is clear beats a collision
   the ego would be at fault for.
4. The ego is commanded the first step of the best proposal. Since every proposal starts from the ego's current
   acceleration and lateral speed and moves at a bounded jerk, the command sequence is smooth (the tracking).

Vectorised over proposals x agents x steps; the rollout loops over the horizon's steps only. Copyable and
deterministic (the exact oracle deep-copies it and pickles it into the SUMO worker). Ego frame below: x along the
road axis at the ego (its heading without the lateral motion it was commanded), y to the left.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numba import njit, types

from simharness.metrics.safety import TTC_BEHIND_DEG, TTC_STOPPED
from simharness.planners import EgoLimits, ego_axis, rows_of
from simharness.scene import AgentType, Forecast, Scene, heading_velocity
from simharness.sim.base import EgoCommand, RoadGeometry
from simharness.sim.highway.dynamics import half_extents


@dataclasses.dataclass(frozen=True)
class PDMConfig:
    """Proposals, their motion model and the weights of their scores (tuned on seeds 1000-1019 and 0-9 of the stress
    scenarios; the held-out scored seeds are 700-749)."""

    speed_fractions: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)  # target speeds, shares of the ego's max
    lateral_offsets: tuple[float, ...] = (0.0, -0.75, 0.75, -1.5, 1.5, -3.0, 3.0)  # m from the reference, + left
    emergency_offsets: tuple[float, ...] = (0.0,)  # offsets of the proposals that may brake at the ego's limit
    horizon_s: float = 4.0  # s of the forecast used (shorter if the forecast is)
    # m: agents of `now` this close to the ego are planned around (and forecast: the loop's radius); oncoming traffic
    # closes at up to twice the speed limit, and at 60 m a car turning across came into view too late to slow for it
    radius: float = 90.0
    idm_headway_s: float = 1.0  # IDM's desired time gap
    idm_standstill: float = 2.0  # m: IDM's gap at standstill
    idm_decel: float = 3.0  # m/s^2: IDM's comfortable deceleration b
    comfort_decel: float = 3.6  # m/s^2: the hardest braking of a comfortable proposal (nuPlan's bound 4.05)
    comfort_jerk: float = 6.5  # m/s^3: jerk of a comfortable proposal (nuPlan's bound 8.37)
    emergency_jerk: float = 30.0  # m/s^3: jerk of an emergency proposal
    lateral_accel: float = 1.5  # m/s^2: how fast the lateral speed changes (nuPlan's bound 4.89)
    corridor_margin: float = 0.3  # m beside the boxes: who counts as the leader of a proposal
    leader_lookahead_s: float = 1.5  # s: an agent entering the corridor this soon is a leader already
    # s: the same for a pedestrian forecast to cross the road, yielded to early enough to stop for it comfortably
    # (v / comfort_decel is 3.5 s at 45 km/h): a vehicle that will cross is passed or followed, a crossing
    # pedestrian is waited for
    pedestrian_lookahead_s: float = 3.0
    crossing_m: float = 2.0  # m across the road axis within the horizon: a pedestrian forecast to cross it
    margin_long: float = 0.3  # m ahead and behind the boxes: collision check
    margin_lat: float = 0.15  # m beside the boxes: collision check
    ttc_threshold: float = 1.5  # s: the scorecard's near-miss threshold
    ttc_probes: int = 8  # constant-velocity probes from 0 to ttc_threshold itself
    w_progress: float = 5.0
    w_ttc: float = 5.0
    w_comfort: float = 2.0
    w_consistency: float = 0.02  # tie-break: a change of target speed (share) or offset (per 3 m) costs this much


class PDMPlanner:
    """Lane-less PDM-Closed (see the module docstring).

    limits: ego kinematics; config: proposals and weights; road: drivable area (proposals leaving it are
    discarded). `last_rollout` (F, 2): the chosen proposal's path, world m; `last_score` (C,).
    """

    def __init__(self, limits: EgoLimits | None = None, config: PDMConfig | None = None,
                 road: RoadGeometry | None = None) -> None:
        self.limits = limits or EgoLimits()
        self.config = cfg = config or PDMConfig()
        self.set_road(road)
        v, d = np.meshgrid(np.asarray(cfg.speed_fractions, np.float64), np.asarray(cfg.lateral_offsets, np.float64),
                           indexing="ij")
        ve, de = np.meshgrid(np.asarray(cfg.speed_fractions, np.float64),
                             np.asarray(cfg.emergency_offsets, np.float64), indexing="ij")
        self._share = np.concatenate([v.ravel(), ve.ravel()])  # (C,) target speed / max speed
        self._off = np.concatenate([d.ravel(), de.ravel()])  # (C,) m
        emergency = np.arange(self._share.size) >= v.size
        self._jerk = np.where(emergency, cfg.emergency_jerk, cfg.comfort_jerk)  # (C,) m/s^3
        self._decel = np.where(emergency, self.limits.max_decel, cfg.comfort_decel)  # (C,) m/s^2
        # (K,) s: up to the threshold itself, so no time-to-collision the scorecard calls a near miss slips between
        self._taus = np.linspace(0.0, cfg.ttc_threshold, max(cfg.ttc_probes, 2))
        self.reset()

    def set_road(self, road: RoadGeometry | None) -> None:
        """Drivable area the proposals must stay on (None: unconstrained)."""
        self.road = road if road is not None and road.drivable else None

    def reset(self) -> None:
        """Forget the last plan (start of an episode)."""
        self._acc = 0.0  # m/s^2: last commanded acceleration
        self._vlat = 0.0  # m/s: last commanded lateral speed
        self._ref: np.ndarray | None = None  # (2,) world point on the reference line
        self._choice = 1.0  # last chosen target speed share
        self.last_score: np.ndarray | None = None
        self.last_rollout: np.ndarray | None = None

    # ------------------------------------------------------------------ the others
    def others(self, now: Scene, forecast: Forecast | None, frames: int, dt: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every agent of `now` within `radius` of the ego over the horizon: rows (M,), xy (M, F + 1, 2) world m
        (column 0: now), heading (M, F + 1) rad, forecast (M,) bool (False: extrapolated at constant velocity)."""
        e = now.ego
        xy_now = now.xy[:, -1].astype(np.float64)
        near = now.valid[:, -1] & (np.linalg.norm(xy_now - xy_now[e], axis=-1) <= self.config.radius)
        near[e] = False
        rows = np.flatnonzero(near)
        h_now = now.heading[rows, -1].astype(np.float64)
        vel = heading_velocity(now.speed[rows, -1].astype(np.float64), h_now)
        steps = np.arange(frames + 1, dtype=np.float64) * dt
        xy = xy_now[rows][:, None] + vel[:, None] * steps[None, :, None]  # (M, F + 1, 2) constant velocity
        covered = np.zeros(rows.size, bool)
        if forecast is not None and len(forecast.agent_id) and rows.size:
            at = rows_of(forecast.agent_id, now.agent_id[rows])  # (M,) row in the forecast or -1
            mean = np.asarray(forecast.mean, np.float64)
            covered = (at >= 0) & np.isfinite(mean[np.maximum(at, 0)]).all((1, 2)) if mean.shape[1] else covered
            if covered.any():
                path = mean[at[covered]]  # (K, H, 2)
                h = min(path.shape[1], frames)
                xy[covered, 1:h + 1] = path[:, :h]
                if h < frames:  # pad at the forecast's last velocity
                    prev = path[:, h - 2] if h >= 2 else xy_now[rows[covered]]
                    last_v = path[:, h - 1] - prev
                    xy[covered, h + 1:] = path[:, h - 1][:, None] + last_v[:, None] * np.arange(1, frames - h + 1)[
                        None, :, None]
        step = np.diff(xy, axis=1)  # (M, F, 2)
        moving = np.hypot(step[..., 0], step[..., 1]) > 0.05
        heading = np.concatenate([h_now[:, None], np.where(moving, np.arctan2(step[..., 1], step[..., 0]),
                                                           h_now[:, None])], 1)
        return rows, xy, heading, covered

    # ------------------------------------------------------------------ the plan
    def plan(self, now: Scene, forecast: Forecast | None) -> EgoCommand:
        """The best proposal's first command (module docstring)."""
        cfg, lim = self.config, self.limits
        e = now.ego
        if e < 0:
            raise ValueError("PDMPlanner.plan needs a Scene with its ego row set")
        dt = forecast.dt if forecast is not None else now.dt
        frames = max(1, int(round(cfg.horizon_s / dt)))
        p0, h0, v0 = ego_axis(now, self._vlat)
        fwd, left = np.array([np.cos(h0), np.sin(h0)]), np.array([-np.sin(h0), np.cos(h0)])
        le, we = float(now.length[e]), float(now.width[e])
        lat0 = 0.0 if self._ref is None else float(np.clip((self._ref - p0) @ left, -3.0, 3.0))

        rows, axy, ah, _ = self.others(now, forecast, frames, dt)
        rel = axy - p0
        a_s, a_y = rel @ fwd, rel @ left  # (M, F + 1)
        # Agents that stay far from every proposal's reach over the horizon are left out.
        reach = max(v0, lim.max_speed) * cfg.horizon_s + 10.0
        keep = ((a_s > -20.0) & (a_s < reach) & (np.abs(a_y) < 12.0)).any(1)
        rows, a_s, a_y, ah = rows[keep], a_s[keep], a_y[keep], ah[keep]
        dh = ah - h0
        a_hx, a_hy = half_extents(now.length[rows, None], now.width[rows, None], dh)  # (M, F + 1) on the road axes
        a_vs, a_vy = np.diff(a_s, axis=1) / dt, np.diff(a_y, axis=1) / dt  # (M, F) speeds over each step
        # A pedestrian forecast to cross the road (not one walking along it) is waited for from further out.
        crossing = (now.agent_type[rows] == AgentType.PEDESTRIAN) & (np.ptp(a_y, axis=1) > cfg.crossing_m)
        look = np.where(crossing, round(cfg.pedestrian_lookahead_s / dt),
                        round(cfg.leader_lookahead_s / dt)).astype(np.int64)  # (M,) steps
        c = self._share.size
        r = {k: np.empty((c, frames)) for k in ("s", "y", "v", "vy", "a")}
        f_hit, f_close, v_other = np.empty(c, np.int64), np.empty(c, np.int64), np.empty(c)
        _proposals(np.maximum(self._share * lim.max_speed, 0.1), lat0 + self._off, self._jerk, self._decel,
                   np.array([v0, self._vlat, self._acc, dt, lim.max_accel, max(lim.max_speed, v0),
                             lim.max_lateral_speed, np.tan(lim.max_slip), cfg.idm_standstill, cfg.idm_headway_s,
                             np.sqrt(max(lim.max_accel, 0.1) * cfg.idm_decel), cfg.lateral_accel,
                             cfg.corridor_margin, cfg.margin_long, cfg.margin_lat, le / 2, we / 2,
                             TTC_STOPPED,
                             np.tan(np.deg2rad(180.0 - TTC_BEHIND_DEG))]),
                   self._taus, np.ascontiguousarray(a_s), np.ascontiguousarray(a_y), np.ascontiguousarray(a_vs),
                   np.ascontiguousarray(a_vy), np.ascontiguousarray(a_hx), np.ascontiguousarray(a_hy), look,
                   r["s"], r["y"], r["v"], r["vy"], r["a"], f_hit, f_close, v_other)
        th = np.arctan2(r["vy"], np.maximum(r["v"], 1e-3))  # (C, F) ego heading off the road axis
        collides = f_hit < frames
        # Time to collision: 1 where it stays above the threshold (nuPlan's binary term); a little credit for a later
        # first fall, which only ranks proposals that all fall under it.
        ttc_ok = np.where(f_close >= frames, 1.0, 0.2 * f_close / frames)

        # Drivable area: every corner of the proposal's box at every step.
        ok_road = np.ones(c, bool)
        if self.road is not None:
            exy = p0 + r["s"][..., None] * fwd + r["y"][..., None] * left  # (C, F, 2)
            h = h0 + th
            u = np.stack([np.cos(h), np.sin(h)], -1)[:, :, None] * (np.array([1, 1, -1, -1.0])[:, None] * le / 2)
            w = np.stack([-np.sin(h), np.cos(h)], -1)[:, :, None] * (np.array([1, -1, 1, -1.0])[:, None] * we / 2)
            ok_road = self.road.on_road(exy[:, :, None] + u + w).all((1, 2))

        # Comfort by nuPlan's bounds over the proposal (from the current acceleration).
        acc = r["a"]
        jerk = np.abs(np.concatenate([acc[:, :1] - self._acc, acc[:, 1:] - acc[:, :-1]], 1)) / dt
        lat_acc = np.abs(np.concatenate([r["vy"][:, :1] - self._vlat, r["vy"][:, 1:] - r["vy"][:, :-1]], 1)) / dt
        comfortable = (np.abs(acc).max(1) <= 4.05) & (jerk.max(1) <= 8.37) & (lat_acc.max(1) <= 4.89)

        safe = ok_road & ~collides
        # The emergency proposals are the fallback: taken only where no comfortable one is safe.
        emergency = self._jerk > cfg.comfort_jerk
        if (safe & ~emergency).any():
            safe &= ~emergency
            ok_road = ok_road & ~emergency
        prog = r["s"][:, -1]
        best_prog = prog[safe].max() if safe.any() else prog.max()
        ratio = np.clip(prog / best_prog, 0.0, 1.0) if best_prog > 1.0 else np.ones(c)
        score = (cfg.w_progress * ratio + cfg.w_ttc * ttc_ok + cfg.w_comfort * comfortable) / (
            cfg.w_progress + cfg.w_ttc + cfg.w_comfort)
        # Where every proposal collides: the slowest at its first collision (an ego that has stopped is not at fault),
        # then the latest.
        v_hit = r["v"][np.arange(c), np.minimum(f_hit, frames - 1)]
        fallback = -2.0 - v_hit / max(lim.max_speed, 1.0) + 0.1 * f_hit / frames
        # No faster along the road than the one it touches (stopped behind a merger, say): not the ego's fault on the
        # scorecard, so better than leaving the road.
        fallback += np.where(v_hit <= v_other + 0.1, 1.0, 0.0)
        # Off the road but clear of everyone (onto the shoulder or kerb) beats every collision at speed: a lane-less
        # road's escape, scored as leaving the drivable area, which the scorecard gates as it gates an at-fault one.
        score = np.where(safe, score, np.where(ok_road, fallback, np.where(collides, -3.0, -1.5)))
        # Offset 0 is the line the last choice was heading for.
        score -= cfg.w_consistency * (np.abs(self._share - self._choice) + np.abs(self._off) / 3.0)
        best = int(np.argmax(score))
        cmd = EgoCommand(acceleration=float(r["a"][best, 0]), lateral_velocity=float(r["vy"][best, 0]))
        self._acc, self._vlat = cmd.acceleration, cmd.lateral_velocity
        self._ref = p0 + (lat0 + self._off[best]) * left
        self._choice = float(self._share[best])
        self.last_score = score
        self.last_rollout = p0 + r["s"][best][:, None] * fwd + r["y"][best][:, None] * left
        return cmd


# Compiled (or loaded from numba's cache) on import, so that the SUMO oracle's forked branches inherit it.
_F1, _F2 = types.float64[:], types.float64[:, :]


@njit((_F1, _F1, _F1, _F1, _F1, _F1, _F2, _F2, _F2, _F2, _F2, _F2, types.int64[:], _F2, _F2, _F2, _F2, _F2,
       types.int64[:], types.int64[:], _F1), cache=True)
def _proposals(target: np.ndarray, goal: np.ndarray, jerk: np.ndarray, decel: np.ndarray, p: np.ndarray,
               taus: np.ndarray, a_s: np.ndarray, a_y: np.ndarray, a_vs: np.ndarray, a_vy: np.ndarray,
               a_hx: np.ndarray, a_hy: np.ndarray, look: np.ndarray, s_out: np.ndarray, y_out: np.ndarray,
               v_out: np.ndarray, vy_out: np.ndarray, a_out: np.ndarray, f_hit: np.ndarray, f_close: np.ndarray,
               v_other: np.ndarray) -> None:
    """Roll out and check every proposal of `PDMPlanner.plan`, in the ego frame (x along the road, y left).

    target (C,) m/s: IDM's desired speed; goal (C,) m: lateral position aimed at; jerk (C,) m/s^3, decel (C,) m/s^2:
    the proposal's bounds; p: v0, vy0, a0, dt, max_accel, max_speed, max_lateral_speed, tan(max_slip),
    idm_standstill, idm_headway_s, sqrt(a b), lateral_accel, corridor_margin, margin_long, margin_lat, ego half
    length, ego half width, the speed (m/s) below which the ego stands and the tangent of 180 degrees less the
    bearing beyond which an agent is behind it (`safety.ttc_relevant`); taus (K,) s: time-to-collision probes;
    agents: a_s, a_y (M, F + 1) m, a_hx, a_hy (M, F + 1) half extents on the road axes, column f at f dt; a_vs, a_vy
    (M, F) m/s over each step; look (M,): each agent's leader lookahead, steps. Writes s, y, v, vy, a (C, F) (state
    at the end of each step, acceleration over it); f_hit (C,): the first step that collides (margins added; agents
    behind the ego's centre only while the ego moves sideways towards them), F if none; v_other (C,) m/s: the
    along-road speed of the agent first hit; f_close (C,): the first step where a probe overlaps (no margins) an
    agent not behind the moving ego, i.e. the time-to-collision falls under the threshold, F if none.
    """
    v0, vy0, a0, dt, a_max, v_cap, vy_max, tan_slip = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]
    s0, headway, sqrt_ab, lat_acc, corridor, m_long, m_lat, le2, we2 = p[8], p[9], p[10], p[11], p[12], p[13], \
        p[14], p[15], p[16]
    stopped, behind = p[17], p[18]
    ease = jerk.min()
    n_c, n_f = s_out.shape
    n_m = a_s.shape[0]
    for c in range(n_c):
        s, y, v, vy, a = 0.0, 0.0, v0, vy0, a0
        f_hit[c] = n_f
        v_other[c] = 0.0
        f_close[c] = n_f
        for f in range(n_f):
            # IDM behind the nearest agent ahead in the proposal's corridor, now or within `look` steps that the ego
            # at its present speed has not passed by then: a crosser is followed from before it enters, not after.
            gap, lead_v = np.inf, 0.0
            for m in range(n_m):
                for k in range(f, min(f + look[m], n_f) + 1):
                    rel = a_s[m, k] - s
                    if rel > 0 and abs(a_y[m, k] - y) < we2 + a_hy[m, k] + corridor and \
                            rel - v * (k - f) * dt > -le2 - a_hx[m, k]:
                        g = rel - le2 - a_hx[m, k]
                        if g < gap:
                            gap, lead_v = g, a_vs[m, min(k, n_f - 1)]
                        break
            inter = 0.0
            if gap < np.inf:
                want = s0 + max(0.0, v * headway + v * (v - lead_v) / (2.0 * sqrt_ab))
                inter = (want / max(gap, 0.1)) ** 2
            a_idm = a_max * (1.0 - (v / target[c]) ** 4 - inter)
            # Braking eases off towards standstill at the proposal's jerk (a step early: the steps are discrete), so
            # that stopping is smooth too.
            lo = -min(decel[c], max(np.sqrt(2.0 * jerk[c] * max(v, 0.0)) - jerk[c] * dt,
                                 min(v / dt, jerk[c] * dt)))
            a_des = min(max(a_idm, lo), a_max)
            a = a + min(max(a_des - a, -jerk[c] * dt), ease * dt)  # emergency ones brake fast, ease off gently
            a = max(a, -v / dt)
            v_new = min(v + a * dt, v_cap)
            s += 0.5 * (v + v_new) * dt
            v = v_new
            # Lateral: towards the goal, the lateral speed changed at a bounded acceleration (no overshoot).
            err = goal[c] - y
            cap = min(vy_max, tan_slip * v, np.sqrt(2.0 * lat_acc * abs(err)), abs(err) / dt)
            vy_des = cap if err > 0 else -cap
            vy += min(max(vy_des - vy, -lat_acc * dt), lat_acc * dt)
            y += vy * dt
            s_out[c, f], y_out[c, f], v_out[c, f], vy_out[c, f], a_out[c, f] = s, y, v, vy, a
            # Checks at the step's end: the ego's box on the road axes (heading off the axis by its lateral motion).
            th = np.arctan2(vy, max(v, 1e-3))
            ch, sh = abs(np.cos(th)), abs(np.sin(th))
            e_hx, e_hy = ch * le2 + sh * we2, sh * le2 + ch * we2
            for m in range(n_m):
                sx, sy = e_hx + a_hx[m, f + 1], e_hy + a_hy[m, f + 1]
                ds, dy = a_s[m, f + 1] - s, a_y[m, f + 1] - y
                if f_hit[c] == n_f and abs(ds) < sx + m_long and abs(dy) < sy + m_lat:
                    if ds > 0 or (dy > 0 and vy > 0.1) or (dy < 0 and vy < -0.1):
                        f_hit[c] = f
                        v_other[c] = a_vs[m, f]
                # Time to collision as the scorecard's (`safety.ttc_relevant`): agents not behind the moving ego.
                if f_close[c] == n_f and v > stopped and not (ds < 0 and abs(dy) < -ds * behind):
                    for tau in taus:
                        if abs(ds + (a_vs[m, f] - v) * tau) < sx and abs(dy + (a_vy[m, f] - vy) * tau) < sy:
                            f_close[c] = f
                            break
