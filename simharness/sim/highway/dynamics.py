"""Lane-free mixed traffic on arrays: the state, and the vectorised rules that move it.

Frame: x along the carriageway (direction of travel), y lateral, + left,
0 on the carriageway centre line. Every rule here works on (n,) state arrays
or (R, C) arrays of candidate offsets, so nothing loops over agents in Python;
the searches over (agent, other) pairs are compiled kernels beside this module
(`leaders`, `room`, `crossing`).

Footprints are handled as the axis-aligned boxes that contain each agent's
rotated rectangle (half extents hx, hy), so keeping those boxes apart keeps the
oriented boxes that the collision metric tests apart too.
"""

from __future__ import annotations

import dataclasses

import numpy as np

# np.clip's own ufunc, without its Python-level wrapper (same results, signed zeros included); numpy < 2: np.core
clip = (np._core if hasattr(np, "_core") else np.core).umath.clip

VEHICLE, CROSSING, WALKING = 0, 1, 2  # kinds: drives; crosses the road; walks along its edge

B_EMERGENCY = 8.0  # m/s^2: decelerations beyond this are reported as emergency stops
GAP_MIN = 0.25  # m: bumper gap that the hard speed clamp always keeps (absorbs box growth when turning)
CUT_IN_HORIZON = 1.0  # s: a neighbour drifting into one's band within this counts as a leader
PED_CLAIM_S = 1.5  # s: a crossing pedestrian claims the strip it walks through in this time
LAT_GAIN = 0.8  # 1/s: lateral speed per metre of offset from the target
LAT_ACC = 1.5  # m/s^2: how fast the lateral speed may change
LAT_COST = 0.35  # (m/s)/m: score lost per metre of lateral move
LOOKAHEAD = 80.0  # m: gaps beyond this count as free road when choosing a lateral offset


@dataclasses.dataclass
class TrafficState:
    """All agents as (n,) arrays, rows sorted by `uid` (appends only; removals keep order).

    uid (int64) never reused; agent_id (str); agent_type (int8); kind (int8: VEHICLE, CROSSING, WALKING);
    is_ego (bool); x, y (m); vx, vy (m/s, along and across the road); length, width (m);
    v0 (m/s desired speed); a_max, b_comf (m/s^2); headway (s); s0 (m); vy_max (m/s);
    switch_margin (m/s of gain needed to change lateral target); y_target (m); cross_dir (+1 walks to +y).
    """

    uid: np.ndarray
    agent_id: np.ndarray
    agent_type: np.ndarray
    kind: np.ndarray
    is_ego: np.ndarray
    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    length: np.ndarray
    width: np.ndarray
    v0: np.ndarray
    a_max: np.ndarray
    b_comf: np.ndarray
    headway: np.ndarray
    s0: np.ndarray
    vy_max: np.ndarray
    switch_margin: np.ndarray
    y_target: np.ndarray
    cross_dir: np.ndarray

    _DTYPES = {"uid": np.int64, "agent_id": object, "agent_type": np.int8, "kind": np.int8, "is_ego": bool}

    @classmethod
    def empty(cls) -> TrafficState:
        return cls(**{f.name: np.zeros(0, cls._DTYPES.get(f.name, np.float64)) for f in dataclasses.fields(cls)})

    @property
    def n(self) -> int:
        return int(self.uid.size)

    def append(self, **cols: np.ndarray) -> None:
        """Add rows (each column an (m,) array; every field required)."""
        for f in dataclasses.fields(self):
            new = np.asarray(cols[f.name], dtype=self._DTYPES.get(f.name, np.float64)).reshape(-1)
            setattr(self, f.name, np.concatenate([getattr(self, f.name), new]))

    def keep(self, mask: np.ndarray) -> None:
        """Drop the rows where mask is False."""
        for f in dataclasses.fields(self):
            setattr(self, f.name, getattr(self, f.name)[mask])

    def headings(self) -> np.ndarray:
        """(n,) radians CCW from +x: direction of motion; crossing pedestrians face their crossing."""
        walk = np.where(self.vy != 0, np.sign(self.vy), self.cross_dir) * (np.pi / 2)
        return np.where(self.kind == CROSSING, walk, np.arctan2(self.vy, self.vx))


def half_extents(length: np.ndarray, width: np.ndarray, heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) footprints and headings -> (hx, hy) (n,) half sizes of the axis-aligned box around each."""
    c, s = np.abs(np.cos(heading)), np.abs(np.sin(heading))
    return 0.5 * (length * c + width * s), 0.5 * (length * s + width * c)


def lateral_claims(s: TrafficState, hy: np.ndarray, walking_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lateral interval each agent occupies now or will soon: (lo, hi) (n,) m.

    Vehicles extend their box by their lateral drift over CUT_IN_HORIZON; a crossing
    pedestrian that is walking (walking_now) claims the strip it crosses in PED_CLAIM_S.
    """
    ext = np.where(s.kind == CROSSING, walking_now * s.cross_dir * (s.v0 * PED_CLAIM_S + 0.3),
                   s.vy * CUT_IN_HORIZON)
    return s.y - hy + np.minimum(ext, 0.0), s.y + hy + np.maximum(ext, 0.0)


def idm_acceleration(v: np.ndarray, v0: np.ndarray, a: np.ndarray, b: np.ndarray, headway: np.ndarray,
                     s0: np.ndarray, gap: np.ndarray, v_lead: np.ndarray, coolness: float = 0.99) -> np.ndarray:
    """IDM on bumper gaps, softened by the constant-acceleration heuristic (Treiber and Kesting's ACC model).

    Arrays in SI units, broadcast together -> m/s^2; inf gap means free road. Plain IDM brakes far too hard when
    someone cuts in close but faster (a lane-free road does this all the time); the heuristic only
    brakes as hard as keeping the gap open against a non-accelerating leader needs.
    """
    free = 1.0 - (v / np.maximum(v0, 0.1)) ** 4
    s_star = s0 + np.maximum(0.0, v * headway + v * (v - v_lead) / (2.0 * np.sqrt(a * b)))
    lead = np.isfinite(gap)
    g = np.where(lead, np.maximum(gap, 0.01), 1.0)
    a_idm = a * (free - np.where(lead, (s_star / g) ** 2, 0.0))
    closing = np.where(lead, np.maximum(v - v_lead, 0.0), 0.0)
    a_cah = -closing**2 / (2.0 * g)
    soft = (1 - coolness) * a_idm + coolness * (a_cah + b * np.tanh((a_idm - a_cah) / b))
    return np.maximum(np.where(a_idm >= a_cah, a_idm, soft), -B_EMERGENCY * 1.5)


def clamp_to_leaders(v_new: np.ndarray, leader: np.ndarray, gap: np.ndarray, dt: float, free: np.ndarray,
                     vx_fixed: np.ndarray) -> np.ndarray:
    """Largest speeds (n,) that keep every bumper gap >= GAP_MIN after the step.

    free: (n,) rows exempt (a commanded ego). vx_fixed: (n,) rows that do not move along x
    (crossing pedestrians). Iterates along leader chains until nothing changes.
    """
    v = np.where(vx_fixed, 0.0, v_new)
    has = np.isfinite(gap) & ~free
    slack = np.where(has, (gap - GAP_MIN) / dt, np.inf)
    for _ in range(max(1, v.size)):
        lim = np.maximum(v[leader] + slack, 0.0) if v.size else v
        new = np.where(has, np.minimum(v, lim), v)
        if np.array_equal(new, v):
            break
        v = new
    return v


def safe_lateral_moves(move: np.ndarray, vx: np.ndarray, length: np.ndarray, width: np.ndarray,
                       hy: np.ndarray, up: np.ndarray, down: np.ndarray, dt: float) -> np.ndarray:
    """Largest of (move, move/2, 0) (n,) m whose box, turned to the new heading, stays within the room.

    Turning grows the box on both sides, so the new left edge must rise by at most `up` and the
    right edge drop by at most `down` (n,) m; hy (n,) is the current half width. Moving 0 straightens
    the agent, which never grows its box.
    """
    opts = np.zeros((3, move.size))
    opts[0], opts[1] = move, 0.5 * move
    heading = np.arctan2(opts[:2] / dt, vx)  # moving 0 is always allowed: its box is not looked at
    grow = 0.5 * (length * np.abs(np.sin(heading)) + width * np.abs(np.cos(heading))) - hy  # half_extents' hy
    ok = np.ones((3, move.size), bool)
    ok[:2] = (opts[:2] + grow <= up + 1e-9) & (grow - opts[:2] <= down + 1e-9)
    return opts[np.argmax(ok, axis=0), np.arange(move.size)]
