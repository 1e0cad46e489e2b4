"""Separating-axis tests of oriented boxes, compiled: whether two boxes overlap, and the gap from the ego to others.

Oriented rectangles (centre, heading as its cosine and sine, length, width). The same float64 arithmetic, in
the same order, as `metrics.collisions.boxes_overlap` and `metrics.safety.min_gap` (so the same answers bit for
bit); the trigonometry is left to numpy (the callers pass cosines and sines), so it is numpy's own everywhere.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _spread(px: float, py: float, c: float, s: float, lh: float, wh: float, ux: float, uy: float
            ) -> tuple[float, float]:
    """(min, max) of the projections on the axis (ux, uy) of the four corners of a box (centre px, py m; heading
    cosine c, sine s; half length lh, half width wh m), corners computed as `box_corners` does."""
    fx, fy, lx, ly = c * lh, s * lh, -s * wh, c * wh
    p0 = ((px + fx) + lx) * ux + ((py + fy) + ly) * uy
    p1 = ((px - fx) + lx) * ux + ((py - fy) + ly) * uy
    p2 = ((px - fx) - lx) * ux + ((py - fy) - ly) * uy
    p3 = ((px + fx) - lx) * ux + ((py + fy) - ly) * uy
    return min(min(p0, p1), min(p2, p3)), max(max(p0, p1), max(p2, p3))


@njit(cache=True)
def may_overlap(x: float, y: float, ca: float, sa: float, la: float, wa: float, cb: float, sb: float, lb: float,
                wb: float) -> bool:
    """False only where `overlap` is surely False: the centres (x, y m: a's minus b's) lie more than 1e-6 m beyond
    the two boxes' projection radii along one of the four box axes (a handful of operations instead of 32)."""
    cos_d, sin_d = abs(ca * cb + sa * sb), abs(sa * cb - ca * sb)  # |cos|, |sin| of the angle between them
    la, wa, lb, wb = 0.5 * la, 0.5 * wa, 0.5 * lb, 0.5 * wb
    return (abs(x * ca + y * sa) <= la + lb * cos_d + wb * sin_d + 1e-6  # along a's heading
            and abs(y * ca - x * sa) <= wa + lb * sin_d + wb * cos_d + 1e-6  # across a
            and abs(x * cb + y * sb) <= lb + la * cos_d + wa * sin_d + 1e-6  # along b's heading
            and abs(y * cb - x * sb) <= wb + la * sin_d + wa * cos_d + 1e-6)  # across b


@njit(cache=True)
def overlap(ax: float, ay: float, ca: float, sa: float, la: float, wa: float, bx: float, by: float, cb: float,
            sb: float, lb: float, wb: float) -> bool:
    """Whether box a (centre ax, ay m; heading cosine ca, sine sa; length la, width wa m) and box b overlap:
    no axis of either separates them by more than 1e-9 m (touching counts as overlap), as `boxes_overlap`."""
    for ux, uy in ((ca, sa), (-sa, ca), (cb, sb), (-sb, cb)):
        a_lo, a_hi = _spread(ax, ay, ca, sa, la / 2, wa / 2, ux, uy)
        b_lo, b_hi = _spread(bx, by, cb, sb, lb / 2, wb / 2, ux, uy)
        if a_hi < b_lo - 1e-9 or b_hi < a_lo - 1e-9:
            return False
    return True


@njit(cache=True)
def gaps(rel: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray, cos_q: np.ndarray, sin_q: np.ndarray,
         length: np.ndarray, width: np.ndarray, e: int, rows: np.ndarray) -> np.ndarray:
    """`safety.min_gap` of the ego (row e) to the agents `rows` (P,): (P,) float32 m, the largest separation along
    the four box axes, 0 where the boxes overlap.

    rel (P, 2) m: the ego's centre minus each agent's; cos_h, sin_h (n,) of the headings, cos_q, sin_q (n,) of the
    headings plus pi / 2 (numpy's values); length, width (n,) m.
    """
    out = np.empty(rows.size, np.float32)
    for p in range(rows.size):
        i = rows[p]
        fa0, fa1, fb0, fb1 = cos_h[i], sin_h[i], cos_h[e], sin_h[e]
        la, wa, lb, wb = length[i] / 2, width[i] / 2, length[e] / 2, width[e] / 2
        sep = -np.inf
        for k in range(4):
            if k == 0:
                ax, ay = cos_h[i], sin_h[i]
            elif k == 1:
                ax, ay = cos_q[i], sin_q[i]
            elif k == 2:
                ax, ay = cos_h[e], sin_h[e]
            else:
                ax, ay = cos_q[e], sin_q[e]
            s = (abs(ax * rel[p, 0] + ay * rel[p, 1])
                 - (abs(ax * fa0 + ay * fa1) * la + abs(ax * -fa1 + ay * fa0) * wa)
                 - (abs(ax * fb0 + ay * fb1) * lb + abs(ax * -fb1 + ay * fb0) * wb))
            sep = s if k == 0 else max(sep, s)
        out[p] = np.float32(max(sep, 0.0))
    return out


@njit(cache=True)
def overlaps_with(x: np.ndarray, y: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray, length: np.ndarray,
                  width: np.ndarray, rows: np.ndarray, e: int) -> np.ndarray:
    """(P,) bool: whether the boxes of `rows` (P,) overlap the box of row e (`overlap`). x, y (n,) m: centres;
    cos_h, sin_h (n,): of the headings (numpy's values); length, width (n,) m."""
    out = np.empty(rows.size, np.bool_)
    for p in range(rows.size):
        i = rows[p]
        out[p] = overlap(x[i], y[i], cos_h[i], sin_h[i], length[i], width[i], x[e], y[e], cos_h[e], sin_h[e],
                         length[e], width[e])
    return out
