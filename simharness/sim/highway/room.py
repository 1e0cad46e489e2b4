"""Lateral room beside each agent, compiled: the free distance to the nearest box in its side window, left and right.

The side window holds the agents beside one, or close enough ahead or behind that one must not move into
their band: the follower's safe gap is half its standstill gap, half a second of its speed, plus one second of
closing speed. One scan along x from each agent, both ways, that stops where every gap exceeds the largest
margin anyone has, with the float64 arithmetic of the (n, n) table formulation it replaces (same results bit for
bit), instead of tens of numpy calls on (n, n) tables.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def lateral_room(order: np.ndarray, x: np.ndarray, y: np.ndarray, hx: np.ndarray, hy: np.ndarray, vx: np.ndarray,
                 s0: np.ndarray, is_ego: np.ndarray, ignore_ego: bool, ego_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Free lateral distance (n,) m to the nearest box in the side window on the left (+y) and on the right.

    order (n,) int: the rows sorted by x (`np.argsort(x)`; ties in any order); x, y, hx, hy (n,) m: centres and
    half extents of the axis-aligned boxes; vx (n,) m/s; s0 (n,) m standstill
    gaps; is_ego (n,) bool. ignore_ego: a background agent's window holds the ego only while their bumper gap is
    below ego_gap m (the `ignore` reaction: -inf, never; `cut_in`: the lateral minimum gap, side by side only).
    Boxes that overlap one's own band (lateral gap below -1e-9 m) are ahead or behind, not beside, and do not
    count. inf where the window holds nothing on that side.
    """
    n = x.size
    left = np.full(n, np.inf)
    right = np.full(n, np.inf)
    if n == 0:
        return left, right
    hx_max = hx.max()
    follower = 0.5 * s0 + 0.5 * vx  # (n,) the follower's own part of the margin
    # No margin exceeds this (rounding is monotone): the scan along x stops where every gap is at least it.
    most = max(max(vx.max() - vx.min(), 0.0) + follower.max(), ego_gap)
    for p in range(n):
        i = order[p]
        skip_ego = ignore_ego and not is_ego[i]
        reach = hx[i] + hx_max
        lb, rb = np.inf, np.inf
        for step in (1, -1):  # ahead, then behind, in x order
            q = p + step
            while 0 <= q < n:
                j = order[q]
                q += step
                dx = x[j] - x[i]
                gap = abs(dx) - (hx[i] + hx[j])
                if abs(dx) - reach >= most:
                    break
                if dx < 0:  # j behind: the margin of j following i
                    margin = max(vx[j] - vx[i], 0.0) + follower[j]
                else:
                    margin = max(vx[i] - vx[j], 0.0) + follower[i]
                inside = gap < margin
                if skip_ego and is_ego[j]:
                    inside = gap < ego_gap
                if not inside:
                    continue
                dy = y[j] - y[i]
                lat_gap = abs(dy) - (hy[i] + hy[j])
                if lat_gap >= -1e-9:
                    if dy > 0:
                        lb = min(lb, lat_gap)
                    elif dy < 0:
                        rb = min(rb, lat_gap)
        left[i], right[i] = lb, rb
    return left, right
