"""The env's observation: the ego and its K nearest agents over the last H frames, in the ego's frame.

Built from the last H `Frame`s directly (no `Scene`): agents are matched across frames by id with one
sorted lookup per frame, and every feature is computed for all (agent, frame) pairs at once.

Features (F = 9 + 9), all clipped to [-1, 1]: ``present, x / range, y / range, vx / 30, vy / 30,
cos(dh), sin(dh), length / 15, width / 3`` and a one-hot `AgentType`; x ahead and y left of the ego at
the current frame, dh the heading relative to the ego's now. Absent rows and frames are all zero.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np

from simharness.scene import AgentType
from simharness.sim.base import Frame

FEATURES = 9 + len(AgentType)
SPEED_SCALE = 30.0  # m/s
LENGTH_SCALE = 15.0  # m
WIDTH_SCALE = 3.0  # m
_ONEHOT = np.eye(len(AgentType), dtype=np.float32)


@dataclass(frozen=True)
class _Indexed:
    """A frame with its ids sorted once, for matching agents across frames, and their states in that order."""

    frame: Frame
    sorted_ids: np.ndarray  # (n,) agent_id, sorted
    states: np.ndarray  # (n, 4) float64 x, y (m), heading (rad), speed (m/s), in sorted_ids order


class History:
    """The last `frames` frames, oldest first."""

    def __init__(self, frames: int) -> None:
        self._items: collections.deque[_Indexed] = collections.deque(maxlen=frames)

    def clear(self) -> None:
        self._items.clear()

    def append(self, frame: Frame) -> None:
        order = np.argsort(frame.agent_id, kind="stable")
        states = np.column_stack([frame.xy, frame.heading, frame.speed])[order].astype(np.float64)
        self._items.append(_Indexed(frame, frame.agent_id[order], states))

    @property
    def frames(self) -> list[Frame]:
        return [i.frame for i in self._items]

    @property
    def now(self) -> Frame:
        return self._items[-1].frame

    def __len__(self) -> int:
        return len(self._items)

    def track(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Positions of agents `ids` (m,) over the held frames: xy (m, T, 2) m, heading (m, T) rad,
        speed (m, T) m/s and present (m, T) bool (zeros where absent)."""
        m, t = len(ids), len(self._items)
        states = np.zeros((m, t, 4))
        present = np.zeros((m, t), bool)
        at = np.zeros((m, t), np.intp)  # row of each (agent, frame) in the frames' states stacked
        start = 0
        for j, item in enumerate(self._items):  # H frames, each one vectorised lookup
            n = len(item.sorted_ids)
            if n and m:
                pos = np.minimum(np.searchsorted(item.sorted_ids, ids), n - 1)
                present[:, j] = item.sorted_ids[pos] == ids
                at[:, j] = pos + start
            start += n
        if start and m:
            states = np.where(present[..., None], np.concatenate([i.states for i in self._items])[at], 0.0)
        return states[..., :2], states[..., 2], states[..., 3], present


def nearest(frame: Frame, k: int, obs_range: float) -> np.ndarray:
    """Rows of the (at most) k agents nearest the ego within obs_range m, nearest first: (<= k,) int."""
    e = frame.ego
    d = np.hypot(*(frame.xy.astype(np.float64) - frame.xy[e].astype(np.float64)).T)
    d[e] = np.inf
    cand = np.flatnonzero(d <= obs_range)
    return cand[np.argsort(d[cand], kind="stable")][:k]


def ego_rotation(frame: Frame) -> tuple[np.ndarray, np.ndarray, float]:
    """(origin (2,) m, world -> ego rotation (2, 2), ego heading rad) at the ego's current pose."""
    e = frame.ego
    h0 = float(frame.heading[e])
    c, s = np.cos(h0), np.sin(h0)
    return frame.xy[e].astype(np.float64), np.array([[c, s], [-s, c]]), h0


def agents_observation(history: History, k: int, h: int, obs_range: float) -> tuple[np.ndarray, np.ndarray]:
    """(K + 1, H, F) float32 observation and the rows (in the current frame) of the observed neighbours."""
    obs = np.zeros((k + 1, h, FEATURES), np.float32)
    frame = history.now
    e = frame.ego
    if e < 0:
        return obs, np.zeros(0, int)
    near = nearest(frame, k, obs_range)
    rows = np.concatenate([[e], near]).astype(int)
    xy, heading, speed, present = history.track(frame.agent_id[rows])
    p0, rot, h0 = ego_rotation(frame)
    m, t = present.shape
    feats = np.empty((m, t, FEATURES))
    feats[..., 0] = 1.0
    feats[..., 1:3] = (xy - p0) @ rot.T / obs_range
    dh = heading - h0
    cos_dh, sin_dh = np.cos(dh), np.sin(dh)
    feats[..., 3] = speed * cos_dh / SPEED_SCALE  # velocity in the ego frame: rotate by -h0
    feats[..., 4] = speed * sin_dh / SPEED_SCALE
    feats[..., 5] = cos_dh
    feats[..., 6] = sin_dh
    feats[..., 7] = (frame.length[rows] / LENGTH_SCALE)[:, None]
    feats[..., 8] = (frame.width[rows] / WIDTH_SCALE)[:, None]
    feats[..., 9:] = _ONEHOT[frame.agent_type[rows]][:, None]
    np.clip(feats, -1.0, 1.0, out=feats)
    feats *= present[..., None]
    obs[:m, h - t:] = feats  # right-aligned: the last column is now
    return obs, near
