"""Time to collision of the ego, compiled: the first sampled time at which its box overlaps another's.

Under constant velocity the centres of two boxes that overlap are within the sum of their half-diagonals
(`reach`), which holds on one interval of time (a quadratic in tau); of the sampled times in it, only those
where the four-axis projection bound (`separating_axis.may_overlap`) allows an overlap get the exact
separating-axis test (`separating_axis.overlap`). One pass over the agents and their sampled times, with the float64
arithmetic of the numpy formulation it replaces (the same times bit for bit), instead of about seventy numpy
calls. `ttc_and_gap` adds the ego's smallest separating-axis gap, for the reward's safety terms in one call.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from simharness.metrics.separating_axis import gaps, may_overlap, overlap


@njit(cache=True)
def min_ttc(xy: np.ndarray, rel: np.ndarray, d: np.ndarray, reach: np.ndarray, vel: np.ndarray, cos_h: np.ndarray,
            sin_h: np.ndarray, length: np.ndarray, width: np.ndarray, e: int, taus: np.ndarray, horizon: float,
            cap: float) -> float:
    """First of the sampled times taus (K,) s, ascending, at which the ego's box (row e) overlaps another's when
    every agent keeps its velocity; cap (s) when none does.

    xy (n, 2) m: centres; rel (n, 2) m: centres minus the ego's; d (n,) m: their norms; reach (n,) m: sums of
    half-diagonals (plus a tolerance); vel (n, 2) m/s; cos_h, sin_h (n,): of the headings (numpy's values);
    length, width (n,) m; horizon (s): no interval starting later is looked at.
    """
    ve0, ve1 = vel[e, 0], vel[e, 1]
    cb, sb = cos_h[e], sin_h[e]
    best = np.inf
    for i in range(d.size):
        if i == e:
            continue
        dv0, dv1 = vel[i, 0] - ve0, vel[i, 1] - ve1
        # |rel + dv tau| <= reach  <=>  a tau^2 + 2 b tau + c <= 0
        a = dv0 * dv0 + dv1 * dv1
        b = rel[i, 0] * dv0 + rel[i, 1] * dv1
        c = d[i] * d[i] - reach[i] * reach[i]
        disc = b * b - a * c
        if not (disc >= 0 and (c <= 0 or a > 0)):
            continue
        root = np.sqrt(max(disc, 0.0))
        lo = 0.0 if c <= 0 else (-b - root) / a
        hi = (-b + root) / a if a > 0 else np.inf
        if not (hi >= 0 and lo <= horizon):
            continue
        ca, sa = cos_h[i], sin_h[i]
        for k in range(taus.size):
            tau = taus[k]
            if tau >= best:
                break  # a later time cannot beat the first overlap found
            if not (tau >= lo - 1e-6 and tau <= hi + 1e-6):
                continue
            pa0, pa1 = xy[i, 0] + vel[i, 0] * tau, xy[i, 1] + vel[i, 1] * tau
            pe0, pe1 = xy[e, 0] + ve0 * tau, xy[e, 1] + ve1 * tau
            if not may_overlap(pa0 - pe0, pa1 - pe1, ca, sa, length[i], width[i], cb, sb, length[e], width[e]):
                continue  # the four-axis bound rules an overlap out: no need for the exact test
            if overlap(pa0, pa1, ca, sa, length[i], width[i], pe0, pe1, cb, sb, length[e], width[e]):
                best = tau
                break
    return best if best < np.inf else cap


@njit(cache=True)
def ttc_and_gap(xy: np.ndarray, rel: np.ndarray, d: np.ndarray, half_diagonal: np.ndarray, speed: np.ndarray,
                cos_h: np.ndarray, sin_h: np.ndarray, cos_q: np.ndarray, sin_q: np.ndarray, length: np.ndarray,
                width: np.ndarray, e: int, taus: np.ndarray, horizon: float, ttc_cap: float, gap_cap: float
                ) -> tuple[float, float]:
    """(min time to collision s, min gap m) of the ego (row e): `min_ttc` under constant velocity (capped at
    ttc_cap), and the smallest `separating_axis.gaps` (capped at gap_cap) over the agents whose lower bound
    d / sqrt(2) - reach can beat the smallest centre distance (an upper bound), in one call instead of a dozen
    numpy calls; the float64 operations of the numpy code it replaces, in its order.

    half_diagonal (n,) m: half of hypot(length, width) (numpy's values); speed (n,) m/s; cos_q, sin_q (n,): of the
    headings plus pi / 2 (numpy's values); the rest as `min_ttc`.
    """
    n = d.size
    reach = half_diagonal + half_diagonal[e] + 1e-6  # the sums of half-diagonals (plus a tolerance)
    vel = np.empty((n, 2))
    for i in range(n):
        vel[i, 0] = np.float64(speed[i]) * cos_h[i]
        vel[i, 1] = np.float64(speed[i]) * sin_h[i]
    ttc = min_ttc(xy, rel, d, reach, vel, cos_h, sin_h, length, width, e, taus, horizon, ttc_cap)
    upper = np.inf
    for i in range(n):
        if i != e and d[i] < upper:
            upper = d[i]
    upper = min(upper, gap_cap)
    rows = np.empty(n, np.intp)
    p = 0
    for i in range(n):
        if i != e and d[i] / np.sqrt(2.0) - reach[i] <= upper:
            rows[p] = i
            p += 1
    if p == 0:
        return ttc, gap_cap
    rows = rows[:p]
    ego_minus = np.empty((p, 2))  # the ego's centre minus each candidate's, as `gaps` takes it
    for j in range(p):
        ego_minus[j, 0] = xy[e, 0] - xy[rows[j], 0]
        ego_minus[j, 1] = xy[e, 1] - xy[rows[j], 1]
    gap = gaps(ego_minus, cos_h, sin_h, cos_q, sin_q, length, width, e, rows).min()
    return ttc, min(np.float64(gap), gap_cap)
