"""Recorded paths as routes: each agent's track parameterised by the distance travelled along it.

A replayed agent that reacts to the ego (and the ego itself) moves along its own recorded path: its state is
an arc length s (m) and a speed (m/s), and its position is read back from the path. Beyond either end the
path is extended along its end segment, so an agent held back or pushed ahead stays on a sensible line.
All agents of a scene are kept in padded arrays, so lookups are vectorised over agents.
"""

from __future__ import annotations

import dataclasses

import numpy as np

MIN_STEP = 1e-3  # m: path points closer than this to the previous one add no direction


@dataclasses.dataclass(frozen=True)
class Routes:
    """N recorded paths, padded to P points each.

    pts:    (N, P, 2) float64 path points, m (the valid frames' positions; padding repeats the last)
    s:      (N, P)    float64 arc length at each point, m (non-decreasing; padding repeats the last)
    count:  (N,)      int     real points per path (>= 1)
    s_log:  (N, T)    float64 arc length the recording had reached at each frame (nan outside the track)
    v_log:  (N, T)    float64 speed along the path at each frame, m/s (arc-length differences; nan outside)
    seg_heading: (N, max(P-1, 1)) float64 direction of each segment, rad; a segment too short to have one takes
                 the nearest real segment's before it, else after it, else the track's first recorded heading
    """

    pts: np.ndarray
    s: np.ndarray
    count: np.ndarray
    s_log: np.ndarray
    v_log: np.ndarray
    seg_heading: np.ndarray

    @staticmethod
    def from_tracks(xy: np.ndarray, valid: np.ndarray, heading: np.ndarray, dt: float) -> Routes:
        """Routes of N tracks: xy (N, T, 2) m, valid (N, T), heading (N, T) rad, dt s per frame.

        Frames missing inside a track are bridged by the straight line between its neighbours.
        """
        n, t = valid.shape
        count = np.maximum(valid.sum(1), 1)
        p = int(count.max()) if n else 1
        # Compact each track's valid frames to the front (stable order), pad with its last point.
        order = np.argsort(~valid, axis=1, kind="stable")  # (N, T): valid columns first
        cols = order[:, :p]
        idx = np.minimum(np.arange(p)[None], count[:, None] - 1)  # (N, P)
        cols = np.take_along_axis(cols, idx, 1)
        pts = np.take_along_axis(xy.astype(np.float64), cols[..., None], 1)  # (N, P, 2)
        step = np.linalg.norm(np.diff(pts, axis=1), axis=-1)  # (N, P-1)
        s = np.concatenate([np.zeros((n, 1)), np.cumsum(step, 1)], 1)
        # Arc length per frame: the points' s at their frames, interpolated across gaps, nan outside the track.
        frames = np.arange(t)
        first = np.argmax(valid, 1)
        last = t - 1 - np.argmax(valid[:, ::-1], 1)
        s_log = np.full((n, t), np.nan)
        for i in np.flatnonzero(valid.any(1)):  # one np.interp per track, at load time only
            c = int(count[i])
            s_log[i] = np.interp(frames, cols[i, :c], s[i, :c])
        inside = (frames[None] >= first[:, None]) & (frames[None] <= last[:, None]) & valid.any(1)[:, None]
        s_log[~inside] = np.nan
        v_log = np.gradient(s_log, dt, axis=1) if t > 1 else np.zeros_like(s_log)
        v_log = np.where(np.isnan(v_log) & inside, 0.0, v_log)
        head0 = heading[np.arange(n), first].astype(np.float64) if n else np.zeros(0)
        return Routes(pts=pts, s=s, count=count, s_log=s_log, v_log=np.maximum(v_log, 0.0),
                      seg_heading=_segment_headings(pts, step, head0))

    def at(self, rows: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position and tangent heading of paths `rows` (K,) at arc lengths s (K,) m -> xy (K, 2) m, heading (K,) rad.

        Between points: linear; beyond the ends: along the first / last segment.
        """
        rows = np.asarray(rows)
        s = np.asarray(s, np.float64)
        sp, cnt = self.s[rows], self.count[rows]  # (K, P), (K,)
        k = np.arange(len(rows))
        # Segment j spans points j and j+1: the last one whose start is <= s, clipped to the real segments.
        j = np.clip((sp <= s[:, None]).sum(1) - 1, 0, np.maximum(cnt - 2, 0))
        j1 = np.minimum(j + 1, cnt - 1)
        a, b = self.pts[rows, j], self.pts[rows, j1]
        length = sp[k, j1] - sp[k, j]
        heading = self.seg_heading[rows, np.minimum(j, self.seg_heading.shape[1] - 1)]
        frac = np.where(length > MIN_STEP, (s - sp[k, j]) / np.maximum(length, MIN_STEP), 0.0)
        xy = a + np.clip(frac, 0.0, 1.0)[:, None] * (b - a)
        # Before the first point or past the last, extend along the end segment's direction.
        off = np.where(s < sp[k, 0], s - sp[k, 0], np.where(s > sp[k, cnt - 1], s - sp[k, cnt - 1], 0.0))
        xy = xy + off[:, None] * np.stack([np.cos(heading), np.sin(heading)], -1)
        return xy, heading


def _segment_headings(pts: np.ndarray, step: np.ndarray, head0: np.ndarray) -> np.ndarray:
    """(N, max(P-1, 1)) segment directions (see `Routes.seg_heading`): pts (N, P, 2), step (N, P-1) m, head0 (N,)."""
    n = len(pts)
    if step.shape[1] == 0:
        return head0[:, None].copy()
    d = np.diff(pts, axis=1)
    raw = np.arctan2(d[..., 1], d[..., 0])
    real = step > MIN_STEP
    jj = np.broadcast_to(np.arange(step.shape[1])[None], step.shape)
    before = np.maximum.accumulate(np.where(real, jj, -1), axis=1)  # last real segment at or before
    after = np.minimum.accumulate(np.where(real, jj, step.shape[1])[:, ::-1], axis=1)[:, ::-1]  # first at or after
    use = np.where(before >= 0, before, after)
    ok = use < step.shape[1]
    rows = np.arange(n)[:, None]
    return np.where(ok, raw[rows, np.minimum(use, step.shape[1] - 1)], head0[:, None])
