"""Lane-free mixed traffic on arrays: the state, and the vectorised rules that move it.

Frame: x along the carriageway (direction of travel), y lateral, + left,
0 on the carriageway centre line. Every rule works on (n,) state arrays and
(n, n) pairwise arrays (row i = the agent deciding, column j = the other), so
nothing loops over agents or pairs in Python.

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


def may_overlap(rel: np.ndarray, ha: np.ndarray, la: np.ndarray, wa: np.ndarray, hb: float, lb: float,
                 wb: float) -> np.ndarray:
    """(P,) bool, False only where `boxes_overlap` is surely False: the centres (rel (P, 2) m, a minus b)
    lie more than 1e-6 m beyond the two boxes' projection radii along one of the four box axes."""
    ca, sa, cb, sb = np.cos(ha), np.sin(ha), np.cos(hb), np.sin(hb)
    cos_d, sin_d = np.abs(ca * cb + sa * sb), np.abs(sa * cb - ca * sb)  # |cos|, |sin| of the angle between them
    la, wa, lb, wb = 0.5 * la, 0.5 * wa, 0.5 * lb, 0.5 * wb
    x, y = rel[:, 0], rel[:, 1]
    ok = np.abs(x * ca + y * sa) <= la + lb * cos_d + wb * sin_d + 1e-6  # along a's heading
    ok &= np.abs(y * ca - x * sa) <= wa + lb * sin_d + wb * cos_d + 1e-6  # across a
    ok &= np.abs(x * cb + y * sb) <= lb + la * cos_d + wa * sin_d + 1e-6  # along b's heading
    ok &= np.abs(y * cb - x * sb) <= wb + la * sin_d + wa * cos_d + 1e-6  # across b
    return ok


@dataclasses.dataclass(frozen=True)
class Pairwise:
    """(n, n) relations, row i to column j.

    dx, dy:   position of j relative to i (m)
    gap:      bumper-to-bumper gap along x (m), |dx| minus half lengths; negative when the boxes overlap in x
    lat_gap:  side-to-side gap along y (m); negative when the boxes overlap in y
    """

    dx: np.ndarray
    dy: np.ndarray
    gap: np.ndarray
    lat_gap: np.ndarray


def pairwise(x: np.ndarray, y: np.ndarray, hx: np.ndarray, hy: np.ndarray) -> Pairwise:
    """(n,) centres and half extents -> `Pairwise` (n, n)."""
    dx = x[None, :] - x[:, None]
    dy = y[None, :] - y[:, None]
    return Pairwise(dx, dy, np.abs(dx) - (hx[:, None] + hx[None, :]), np.abs(dy) - (hy[:, None] + hy[None, :]))


def lateral_claims(s: TrafficState, hy: np.ndarray, walking_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lateral interval each agent occupies now or will soon: (lo, hi) (n,) m.

    Vehicles extend their box by their lateral drift over CUT_IN_HORIZON; a crossing
    pedestrian that is walking (walking_now) claims the strip it crosses in PED_CLAIM_S.
    """
    ext = np.where(s.kind == CROSSING, walking_now * s.cross_dir * (s.v0 * PED_CLAIM_S + 0.3),
                   s.vy * CUT_IN_HORIZON)
    return s.y - hy + np.minimum(ext, 0.0), s.y + hy + np.maximum(ext, 0.0)


def find_leaders(
    pw: Pairwise, y: np.ndarray, hy: np.ndarray, claim_lo: np.ndarray, claim_hi: np.ndarray,
    sees: np.ndarray | None, margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Lane-free leader: nearest agent ahead whose box comes within `margin` (m) of one's width band, or
    whose claim does (too narrow a gap to pass beside counts as the same band).

    sees: (n, n) bool, row i takes column j into account; None: everyone sees everyone else. Returns
    leader (n,) int row and gap (n,) bumper gap in m (inf where there is no leader; >= 0.01 where boxes
    already overlap).
    """
    cand = (claim_lo[None, :] < (y + hy + margin)[:, None]) & (claim_hi[None, :] > (y - hy - margin)[:, None])
    cand &= pw.gap > 0
    cand |= pw.lat_gap < margin  # in the band, or claiming it with room ahead
    cand &= pw.dx > 0
    if sees is not None:
        cand &= sees
    return masked_argmin(np.maximum(pw.gap, 0.01), cand)


def masked_argmin(values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise argmin of values (R, m) m among the True entries of mask (R, m), ties to the first, and its
    value: (R,) int (0 where a row has none) and (R,) m (inf where it has none). values must be finite."""
    if values.shape[1] == 0:
        return np.zeros(values.shape[0], np.intp), np.full(values.shape[0], np.inf)
    v = np.where(mask, values, np.inf)
    j = np.argmin(v, axis=1)
    best = v[np.arange(v.shape[0]), j]
    j[best == np.inf] = 0
    return j, best


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


def side_windows(pw: Pairwise, vx: np.ndarray, s0: np.ndarray, sees: np.ndarray | None) -> np.ndarray:
    """(n, n) bool: j is beside i, or close enough ahead/behind that i must not move into its band.

    The margin is the follower's safe gap: half its standstill gap, half a second of its
    speed, plus one second of closing speed. sees: (n, n) bool or None (everyone else).
    """
    behind = pw.dx < 0
    follower = 0.5 * s0 + 0.5 * vx  # (n,) the follower's own part of the margin
    follows = np.maximum(vx[:, None] - vx[None, :], 0.0)  # i closing on j ...
    follows += follower[:, None]  # ... plus i's own part: the margin if i follows j
    window = pw.gap < np.where(behind, follows.T, follows)  # j behind: the margin of j following i
    if sees is not None:
        window &= sees
    np.fill_diagonal(window, False)
    return window


def lateral_room(pw: Pairwise, window: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Free lateral distance (n,) to the nearest box in the side window on the left (+y) and right (m)."""
    beside = window & (pw.lat_gap >= -1e-9)  # boxes in one's own band are ahead or behind, not beside
    _, left = masked_argmin(pw.lat_gap, beside & (pw.dy > 0))  # argmin and a gather beat ndarray.min here
    _, right = masked_argmin(pw.lat_gap, beside & (pw.dy < 0))
    return left, right


def band_gaps(gap_rows: np.ndarray, cand_y: np.ndarray, hy_rows: np.ndarray, claim_lo: np.ndarray,
              claim_hi: np.ndarray, ahead: np.ndarray, vx: np.ndarray, margin: float = 0.0,
              horizon: float = np.inf, want: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gap ahead and leader speed for each row at each candidate lateral offset.

    gap_rows (R, n) m: bumper gaps of R deciding rows to everyone (`Pairwise.gap` rows); cand_y (R, C) m;
    hy_rows (R,); claims (n,); ahead (R, n) bool: who may lead; margin (m) as in `find_leaders`;
    horizon (m): leaders farther than this are not looked for (their offsets count as free road);
    want (R, C) bool: the offsets to look at (None: all; the others come back as free road).
    Returns gap (R, C) m (inf: free) and lead speed (R, C) m/s.
    """
    gap, v_lead = np.full(cand_y.shape, np.inf), np.full(cand_y.shape, np.inf)
    g_all = np.maximum(gap_rows, 0.0)
    rows, cols = np.nonzero(ahead & (g_all <= horizon))  # row-major: columns ascend within a row
    counts = np.bincount(rows, minlength=cand_y.shape[0])
    k = int(counts.max()) if rows.size else 0
    if k == 0:
        return gap, v_lead
    # Each row's leader candidates packed left in column order, so argmin breaks ties as over all n columns.
    pos = np.arange(rows.size) - (np.cumsum(counts) - counts)[rows]
    idx = np.zeros((cand_y.shape[0], k), np.intp)
    idx[rows, pos] = cols
    g = np.full((cand_y.shape[0], k), np.inf)
    g[rows, pos] = g_all[rows, cols]
    pr, pc = np.nonzero(np.ones(cand_y.shape, bool) if want is None else want)  # (P,) offsets looked at
    y, h = cand_y[pr, pc], hy_rows[pr]
    cand_idx = idx[pr]  # (P, k)
    overlap = claim_lo[cand_idx] < (y + h + margin)[:, None]
    overlap &= claim_hi[cand_idx] > (y - h - margin)[:, None]
    j, best = masked_argmin(g[pr], overlap)
    gap[pr, pc] = best
    v_lead[pr, pc] = np.where(np.isfinite(best), vx[cand_idx[np.arange(pr.size), j]], np.inf)
    return gap, v_lead


def offset_scores(gap: np.ndarray, v_lead: np.ndarray, v: np.ndarray, v0: np.ndarray, s0: np.ndarray,
                  headway: np.ndarray, b: np.ndarray, cand_y: np.ndarray, y: np.ndarray, kerb_bias: np.ndarray,
                  kerb_y: float) -> np.ndarray:
    """Score (R, C) in m/s of each candidate offset: speed one could hold there, minus the cost of moving.

    gap, v_lead, cand_y (R, C); v, v0, s0, headway, b (comfortable deceleration), y, kerb_bias (R,)
    (m/s per carriageway width that slow vehicles give up by staying away from the kerb at kerb_y).
    An offset whose leader would need harder than comfortable braking scores -inf (unsafe).
    """
    free = gap > LOOKAHEAD
    hold = np.where(free, v0[:, None], v_lead + np.maximum(gap - s0[:, None], 0.0) / (headway[:, None] + 0.5))
    hold = np.minimum(hold, v0[:, None])
    closing = np.maximum(v[:, None] - np.where(free, v[:, None], v_lead), 0.0)
    unsafe = closing**2 > 2.0 * b[:, None] * np.maximum(gap - s0[:, None], 0.01)
    kerb = kerb_bias[:, None] * np.abs(cand_y - kerb_y) / max(abs(kerb_y) * 2, 1e-6)
    return np.where(unsafe, -np.inf, hold - LAT_COST * np.abs(cand_y - y[:, None]) - kerb)


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


def crossing_clear(ped: np.ndarray, s: TrafficState, hx: np.ndarray, hy: np.ndarray, sees: np.ndarray | None,
                   half_width: float) -> np.ndarray:
    """Gap acceptance of crossing pedestrians: (P,) bool, the strip ahead is safe to walk into now.

    ped: (P,) rows of crossing pedestrians; sees (P, n) or None (everyone). A vehicle blocks the strip the pedestrian
    claims (PED_CLAIM_S of walking) when it is level with the pedestrian, or approaching and
    unable to stop comfortably short of it. Off the carriageway the strip is always clear.
    """
    d = s.cross_dir[ped]
    reach = d * (s.v0[ped] * PED_CLAIM_S + 0.3)
    lo = np.minimum(s.y[ped], s.y[ped] + reach) - hy[ped]
    hi = np.maximum(s.y[ped], s.y[ped] + reach) + hy[ped]
    veh = (s.kind != CROSSING)[None, :] if sees is None else (s.kind != CROSSING)[None, :] & sees
    lat = (s.y - hy)[None, :] < hi[:, None]
    lat &= (s.y + hy)[None, :] > lo[:, None]
    front_j = (s.x + hx)[None, :]
    rear_j = (s.x - hx)[None, :]
    near_p, far_p = (s.x[ped] - hx[ped])[:, None], (s.x[ped] + hx[ped])[:, None]
    level = (front_j > near_p - 0.3) & (rear_j < far_p + 0.3)
    dist = near_p - front_j
    v = s.vx[None, :]
    stop = v**2 / (1.5 * s.b_comf[None, :]) + 0.5 * s.s0[None, :] + 0.5 * v  # drivers brake below comfort
    approaching = (dist > 0) & (dist < stop)
    blocked = (veh & lat & (level | approaching)).any(axis=1)
    on_road = (lo < half_width) & (hi > -half_width)
    return ~(blocked & on_road)
