"""Lane-free leader search, compiled: the nearest agent ahead in a lateral band, per agent and per candidate offset.

Each kernel scans the agents ahead in x order and stops where no box farther on can be nearer (a lower bound on
the bumper gap; float rounding is monotone, so the bound holds for the computed gaps too), with the float64
arithmetic of the (n, n) table formulation it replaces (dx = x_j - x_i, bumper gap |dx| - (hx_i + hx_j)): the
results are the same bit for bit, ties going to the lowest row as `np.argmin` over a row does. A small numpy
call costs about a microsecond whatever its size, and the tables took tens of calls per step; here it is one.

`ignore_ego`: background agents do not see the ego (the `ignore` reaction): agent i takes agent j into
account unless i is background and j is the ego.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def leaders(order: np.ndarray, x: np.ndarray, y: np.ndarray, hx: np.ndarray, hy: np.ndarray, claim_lo: np.ndarray,
            claim_hi: np.ndarray, is_ego: np.ndarray, ignore_ego: bool, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Lane-free leader of every agent: nearest agent ahead whose box comes within `margin` (m) of one's width band,
    or whose lateral claim (claim_lo, claim_hi) (n,) m overlaps that band with room ahead.

    order (n,) int: the rows sorted by x (`np.argsort(x)`; ties in any order); x, y, hx, hy (n,) m: centres and
    half extents of the axis-aligned boxes; is_ego (n,) bool. Returns leader (n,) int row (0 where none) and
    gap (n,) bumper gap in m (inf where none; at least 0.01 where the boxes already overlap).
    """
    n = x.size
    leader = np.zeros(n, np.intp)
    best = np.full(n, np.inf)
    if n == 0:
        return leader, best
    hx_max = hx.max()
    for p in range(n):
        i = order[p]
        band_hi, band_lo = y[i] + hy[i] + margin, y[i] - hy[i] - margin
        skip_ego = ignore_ego and not is_ego[i]
        reach = hx[i] + hx_max
        b, bj = np.inf, 0
        for q in range(p + 1, n):  # ahead in x order: the search stops once no box farther on can be nearer
            j = order[q]
            dx = x[j] - x[i]
            if dx - reach > b:
                break  # every gap from here on is at least this (rounding is monotone): none beats or ties b
            if not dx > 0 or (skip_ego and is_ego[j]):
                continue
            gap = abs(dx) - (hx[i] + hx[j])
            if not (claim_lo[j] < band_hi and claim_hi[j] > band_lo and gap > 0):
                if not abs(y[j] - y[i]) - (hy[i] + hy[j]) < margin:
                    continue
            g = max(gap, 0.01)
            if g < b or (g == b and j < bj):  # ties to the lowest row, as np.argmin over a row
                b, bj = g, j
        leader[i], best[i] = bj, b
    return leader, best


@njit(cache=True)
def band_leaders(order: np.ndarray, rows: np.ndarray, cand_y: np.ndarray, want: np.ndarray, x: np.ndarray,
                 hx: np.ndarray, hy: np.ndarray, claim_lo: np.ndarray, claim_hi: np.ndarray, vx: np.ndarray,
                 is_ego: np.ndarray, ignore_ego: bool, margin: float, horizon: float) -> tuple[np.ndarray, np.ndarray]:
    """Gap ahead and leader speed of deciding agents `rows` (R,) at each candidate lateral offset cand_y (R, C) m.

    A leader is an agent ahead (x_j > x_i) whose claim overlaps the offset's band (the agent's half width hy
    plus `margin` m each side). Only offsets where want (R, C) is True are looked at, and only leaders within
    `horizon` m (bumper gap, floored at 0): the others come back as free road. order and the other arrays (n,)
    as in `leaders`; vx m/s. Returns gap (R, C) m (inf: free) and lead speed (R, C) m/s (inf: free).
    """
    r_n, c_n = cand_y.shape
    gap = np.full((r_n, c_n), np.inf)
    v_lead = np.full((r_n, c_n), np.inf)
    n = x.size
    if n == 0:
        return gap, v_lead
    rank = np.empty(n, np.intp)  # position of each row in x order
    for p in range(n):
        rank[order[p]] = p
    hx_max = hx.max()
    near = np.empty(n, np.intp)  # one row's leader candidates, in x order
    near_g = np.empty(n)
    for r in range(r_n):
        i = rows[r]
        skip_ego = ignore_ego and not is_ego[i]
        reach = hx[i] + hx_max
        k = 0
        for q in range(rank[i] + 1, n):  # ahead in x order, up to the horizon
            j = order[q]
            dx = x[j] - x[i]
            if dx - reach > horizon:
                break  # every gap from here on is beyond the horizon (rounding is monotone)
            if not dx > 0 or (skip_ego and is_ego[j]):
                continue
            g = max(abs(dx) - (hx[i] + hx[j]), 0.0)
            if g <= horizon:
                near[k], near_g[k] = j, g
                k += 1
        h = hy[i]
        for c in range(c_n):
            if not want[r, c]:
                continue
            band_hi, band_lo = cand_y[r, c] + h + margin, cand_y[r, c] - h - margin
            b, bj = np.inf, -1
            for m in range(k):
                j = near[m]
                if claim_lo[j] < band_hi and claim_hi[j] > band_lo and (near_g[m] < b or (near_g[m] == b and j < bj)):
                    b, bj = near_g[m], j  # ties to the lowest row, as np.argmin over a row
            if bj >= 0:
                gap[r, c], v_lead[r, c] = b, vx[bj]
    return gap, v_lead
