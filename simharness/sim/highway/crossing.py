"""Gap acceptance of crossing pedestrians, compiled: is the strip ahead of each one safe to walk into now.

One pass over the (pedestrian, agent) pairs with the float64 arithmetic of the (P, n) table formulation it
replaces (same results bit for bit), instead of tens of numpy calls on (P, n) tables.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from simharness.sim.highway.dynamics import PED_CLAIM_S


@njit(cache=True)
def crossing_clear(ped: np.ndarray, x: np.ndarray, y: np.ndarray, hx: np.ndarray, hy: np.ndarray, vx: np.ndarray,
                   v0: np.ndarray, s0: np.ndarray, b_comf: np.ndarray, cross_dir: np.ndarray, crossing: np.ndarray,
                   is_ego: np.ndarray, ignore_ego: bool, half_width: float) -> np.ndarray:
    """(P,) bool: the strip that each crossing pedestrian `ped` (P,) rows claims (PED_CLAIM_S of walking) is clear.

    x, y, hx, hy (n,) m: centres and half extents of the axis-aligned boxes; vx, v0 (n,) m/s; s0 (n,) m;
    b_comf (n,) m/s^2; cross_dir (n,) +1 walks to +y; crossing (n,) bool: crossing pedestrians (they never
    block each other); is_ego (n,) bool, ignore_ego: pedestrians do not see the ego (the `ignore` reaction).
    A vehicle blocks the strip when it is level with the pedestrian, or approaching and unable to stop
    comfortably short of it (drivers brake below comfort). Off the carriageway the strip is always clear.
    """
    out = np.ones(ped.size, np.bool_)
    for p in range(ped.size):
        i = ped[p]
        reach = cross_dir[i] * (v0[i] * PED_CLAIM_S + 0.3)
        lo = min(y[i], y[i] + reach) - hy[i]
        hi = max(y[i], y[i] + reach) + hy[i]
        if not (lo < half_width and hi > -half_width):
            continue
        near_p, far_p = x[i] - hx[i], x[i] + hx[i]
        for j in range(x.size):
            if crossing[j] or (ignore_ego and is_ego[j]):
                continue
            if not (y[j] - hy[j] < hi and y[j] + hy[j] > lo):
                continue
            front_j = x[j] + hx[j]
            if front_j > near_p - 0.3 and x[j] - hx[j] < far_p + 0.3:
                out[p] = False  # level with the pedestrian
                break
            dist = near_p - front_j
            v = vx[j]
            stop = v * v / (1.5 * b_comf[j]) + 0.5 * s0[j] + 0.5 * v
            if dist > 0 and dist < stop:
                out[p] = False  # approaching, too close to stop comfortably
                break
    return out
