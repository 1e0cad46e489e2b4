"""The lateral decision, compiled: each deciding vehicle scores the lateral offsets it may take and picks one.

Score (m/s) of an offset: the speed one could hold there behind its leader (`leaders.band_leaders`),
minus LAT_COST per metre of lateral move, minus a kerb bias for slow vehicles, plus the cut-in bonus; an
offset whose leader would need harder than comfortable braking scores -inf. A vehicle switches when the best
offset beats its current plan by more than its switch margin. Same float64 arithmetic, in the same order, as
the (R, C) numpy formulation it replaces (same targets bit for bit; argmax ties to the first offset), in one
call instead of about fifty.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from simharness.sim.highway.dynamics import LAT_COST, LOOKAHEAD
from simharness.sim.highway.leaders import band_leaders

CUT_IN_BONUS = 3.0  # m/s of score for taking the band in front of the ego (cut_in setting)


@njit(cache=True)
def offset_score(gap: float, v_lead: float, v: float, v0: float, s0: float, headway: float, b: float,
                 cand_y: float, y: float, kerb: float) -> float:
    """Score (m/s) of one offset cand_y (m) with leader gap (m, inf: free road) and speed v_lead (m/s), for a
    vehicle at y (m) driving v (m/s) with desired speed v0, standstill gap s0 (m), headway (s) and comfortable
    deceleration b (m/s^2); kerb (m/s): what the offset costs in kerb bias."""
    if gap > LOOKAHEAD:
        hold, closing = v0, max(v - v, 0.0)
    else:
        hold, closing = v_lead + max(gap - s0, 0.0) / (headway + 0.5), max(v - v_lead, 0.0)
    hold = min(hold, v0)
    if closing * closing > 2.0 * b * max(gap - s0, 0.01):
        return -np.inf
    return hold - LAT_COST * abs(cand_y - y) - kerb


@njit(cache=True)
def choose_offsets(order: np.ndarray, rows: np.ndarray, grid: np.ndarray, stay_allowed: bool, x: np.ndarray,
                   y: np.ndarray, y_target: np.ndarray, hx: np.ndarray, hy: np.ndarray, claim_lo: np.ndarray,
                   claim_hi: np.ndarray, vx: np.ndarray, v0: np.ndarray, s0: np.ndarray, headway: np.ndarray,
                   b_comf: np.ndarray, switch_margin: np.ndarray, room_l: np.ndarray, room_r: np.ndarray,
                   is_ego: np.ndarray, ignore_ego: bool, kerb_bias: np.ndarray, cut_in: np.ndarray, ego_y: float,
                   ego_hy: float, half_width: float, edge_gap: float, min_gap_lat: float) -> np.ndarray:
    """New lateral targets (R,) m of the deciding vehicles `rows` (R,).

    Candidates: the grid (C,) m, where one is, one's current target. An offset may be taken when the box stays
    edge_gap m inside the carriageway (half_width m) and the move fits the lateral room (room_l, room_r (n,) m,
    less min_gap_lat m); staying put is always allowed when stay_allowed (no lane discipline), and the current
    target while it stays inside. order (n,) int: the rows sorted by x. State arrays (n,) in SI units
    (`TrafficState` fields; hx, hy half extents, claims from `lateral_claims`). kerb_bias (R,) m/s per
    carriageway width that slow vehicles lose away from the kerb (+half_width); cut_in (R,) bool: rows that get
    CUT_IN_BONUS in the band of the ego (at ego_y m, half width ego_hy m). Leaders are searched within LOOKAHEAD,
    with half min_gap_lat as the band margin.
    """
    r_n, c_n = rows.size, grid.size + 2
    cand = np.empty((r_n, c_n))
    ok = np.empty((r_n, c_n), np.bool_)
    edge = half_width - edge_gap
    for r in range(r_n):
        i = rows[r]
        for c in range(c_n - 2):
            cand[r, c] = grid[c]
        cand[r, c_n - 2], cand[r, c_n - 1] = y[i], y_target[i]
        up, down = room_l[i] - min_gap_lat, -(room_r[i] - min_gap_lat)
        for c in range(c_n):
            shift = cand[r, c] - y[i]
            ok[r, c] = abs(cand[r, c]) + hy[i] <= edge and shift <= up and shift >= down
        ok[r, c_n - 2] = stay_allowed
        ok[r, c_n - 1] = abs(cand[r, c_n - 1]) + hy[i] <= edge
    gap, v_lead = band_leaders(order, rows, cand, ok, x, hx, hy, claim_lo, claim_hi, vx, is_ego, ignore_ego,
                               0.5 * min_gap_lat, LOOKAHEAD)
    kerb_scale = max(abs(half_width) * 2, 1e-6)
    out = np.empty(r_n)
    for r in range(r_n):
        i = rows[r]
        best, top = 0, -np.inf
        plan = -np.inf
        for c in range(c_n):
            if not ok[r, c]:
                continue
            kerb = kerb_bias[r] * abs(cand[r, c] - half_width) / kerb_scale
            s = offset_score(gap[r, c], v_lead[r, c], vx[i], v0[i], s0[i], headway[i], b_comf[i], cand[r, c], y[i],
                             kerb)
            s += CUT_IN_BONUS if cut_in[r] and abs(cand[r, c] - ego_y) < hy[i] + ego_hy else 0.0
            if s > top:
                best, top = c, s
            if c == c_n - 1:
                plan = s
        if not top > -np.inf:
            gain = -np.inf  # nowhere safe: keep the plan
        elif plan > -np.inf:
            gain = top - plan
        else:
            gain = np.inf
        out[r] = cand[r, best] if gain > switch_margin[i] else y_target[i]
    return out
