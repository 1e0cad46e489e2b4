"""The env's observation: the ego and its K nearest agents over the last H frames, in the ego's frame.

Built from the last H `Frame`s directly (no `Scene`): `History` keeps every agent's state by (frame, id),
so the K + 1 observed agents are gathered over the H frames at once, and one compiled pass writes the
features of all (agent, frame) pairs.

Features (F = 9 + 9), all clipped to [-1, 1]: ``present, x / range, y / range, vx / 30, vy / 30,
cos(dh), sin(dh), length / 15, width / 3`` and a one-hot `AgentType`; x ahead and y left of the ego at
the current frame, dh the heading relative to the ego's now. Absent rows and frames are all zero.
"""

from __future__ import annotations

import collections
from typing import Any

import numpy as np
from numba import njit

from simharness.scene import AgentType, Predictor
from simharness.sim.base import Frame, scene_from_frames

FEATURES = 9 + len(AgentType)
SPEED_SCALE = 30.0  # m/s
LENGTH_SCALE = 15.0  # m
WIDTH_SCALE = 3.0  # m


class History:
    """The last `frames` frames, oldest first, and every agent's state in each of them.

    Each agent id gets an integer code when first seen (since `clear`) and each frame a slot in a ring
    buffer of states by (slot, code), so tracking agents over the held frames is one gather instead of a
    sorted string lookup per frame.
    """

    def __init__(self, frames: int) -> None:
        self._frames: collections.deque[Frame] = collections.deque(maxlen=frames)
        self._codes: dict[Any, int] = {}  # agent id -> code
        self._now_codes = np.zeros(0, np.intp)  # (n,) codes of the newest frame's rows
        self._states = np.zeros((frames, 64, 4))  # (slot, code, 4) float64 x, y (m), heading (rad), speed (m/s)
        self._present = np.zeros((frames, 64), bool)  # (slot, code); states are zero where False
        self._appended = 0  # frames appended since clear(); the newest is in slot (appended - 1) % frames
        self._rings = (np.arange(frames)[:, None] + np.arange(frames)) % frames  # [a % frames]: slots oldest first

    def clear(self) -> None:
        self._frames.clear()
        self._codes.clear()
        self._appended = 0

    def append(self, frame: Frame) -> None:
        ids = frame.agent_id
        # Most frames hold the agents of the frame before in the same rows: then their codes stand.
        if not (self._frames and ids.shape == self.now.agent_id.shape and (ids == self.now.agent_id).all()):
            names = ids.tolist()
            codes = list(map(self._codes.get, names))
            if None in codes:  # agents not seen since clear() take the next codes
                codes = [self._codes.setdefault(i, len(self._codes)) for i in names]
            self._now_codes = np.array(codes, np.intp)
        if len(self._codes) > self._present.shape[1]:  # more agents than room: at least double it
            grow = max(len(self._codes), 2 * self._present.shape[1]) - self._present.shape[1]
            self._states = np.pad(self._states, ((0, 0), (0, grow), (0, 0)))
            self._present = np.pad(self._present, ((0, 0), (0, grow)))
        _put(self._states, self._present, self._appended % self._present.shape[0], self._now_codes, frame.xy,
             frame.heading, frame.speed)
        self._frames.append(frame)
        self._appended += 1

    @property
    def frames(self) -> list[Frame]:
        return list(self._frames)

    @property
    def now(self) -> Frame:
        return self._frames[-1]

    def __len__(self) -> int:
        return len(self._frames)

    def track(self, rows: np.ndarray, origin: np.ndarray | None = None, heading: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The agents in `rows` (m,) of the newest frame over the held frames: xy (m, T, 2) m minus origin (2,) m
        (zeros if None), heading (m, T) rad minus `heading` rad, speed (m, T) m/s and present (m, T) bool (states
        read as zeros where absent, before the subtractions)."""
        t = len(self._frames)
        slots = self._rings[self._appended % t] if t == self._rings.shape[0] else self._rings[0, :t]
        return _gather(self._states, self._present, slots, self._now_codes[rows],
                       np.zeros(2) if origin is None else origin, heading)


@njit(cache=True)
def _gather(states: np.ndarray, present: np.ndarray, slots: np.ndarray, codes: np.ndarray, origin: np.ndarray,
            h0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`History.track` over ring slots (T,) oldest first and agent codes (m,): one pass instead of two gathers and
    the observation's two subtractions (the same float64 operations)."""
    m, t = codes.size, slots.size
    xy, heading, speed = np.empty((m, t, 2)), np.empty((m, t)), np.empty((m, t))
    pres = np.empty((m, t), np.bool_)
    for i in range(m):
        c = codes[i]
        for j in range(t):
            s = slots[j]
            xy[i, j, 0] = states[s, c, 0] - origin[0]
            xy[i, j, 1] = states[s, c, 1] - origin[1]
            heading[i, j] = states[s, c, 2] - h0
            speed[i, j] = states[s, c, 3]
            pres[i, j] = present[s, c]
    return xy, heading, speed, pres


@njit(cache=True)
def _put(states: np.ndarray, present: np.ndarray, slot: int, codes: np.ndarray, xy: np.ndarray, heading: np.ndarray,
         speed: np.ndarray) -> None:
    """One frame into ring slot `slot`: states (slots, codes, 4) float64 x, y (m), heading (rad), speed (m/s) and
    present (slots, codes) bool of the agents with codes (n,), from xy (n, 2), heading (n,), speed (n,) float32
    (widened exactly); every other code of the slot reads as absent, with zero states."""
    states[slot] = 0.0
    present[slot] = False
    for i in range(codes.size):
        c = codes[i]
        states[slot, c, 0] = xy[i, 0]
        states[slot, c, 1] = xy[i, 1]
        states[slot, c, 2] = heading[i]
        states[slot, c, 3] = speed[i]
        present[slot, c] = True


def ego_offsets(frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres xy (n, 2) float64 m, centres minus the ego's (n, 2) m and their norms (n,) m at `frame` (with
    its ego): what the observation and the reward both measure from."""
    xy = frame.xy.astype(np.float64)
    rel = xy - xy[frame.ego]
    return xy, rel, np.hypot(rel[:, 0], rel[:, 1])


@njit(cache=True)
def _ego_and_nearest(d: np.ndarray, e: int, k: int, obs_range: float) -> np.ndarray:
    """(1 + <= k,) rows: the ego's (e), then those of the (at most) k agents nearest it within obs_range m,
    nearest first, from their distances d (n,) m; ties keep row order (a stable sort), as numpy's."""
    cand = np.flatnonzero(d <= obs_range)
    cand = cand[cand != e]
    near = cand[np.argsort(d[cand], kind="mergesort")[:k]]
    rows = np.empty(near.size + 1, np.intp)
    rows[0] = e
    rows[1:] = near
    return rows


def ego_rotation(frame: Frame) -> tuple[np.ndarray, np.ndarray, float]:
    """(origin (2,) m, world -> ego rotation (2, 2), ego heading rad) at the ego's current pose."""
    e = frame.ego
    h0 = float(frame.heading[e])
    c, s = np.cos(h0), np.sin(h0)
    return frame.xy[e].astype(np.float64), np.array([[c, s], [-s, c]]), h0


def agents_observation(history: History, k: int, h: int, obs_range: float, d: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(K + 1, H, F) float32 observation and the rows (in the current frame) of the observed neighbours. d (n,)
    m: the current frame's distances to the ego (`ego_offsets`), if the caller has them."""
    obs = np.zeros((k + 1, h, FEATURES), np.float32)
    frame = history.now
    e = frame.ego
    if e < 0:
        return obs, np.zeros(0, int)
    rows = _ego_and_nearest(ego_offsets(frame)[2] if d is None else d, e, k, obs_range)
    p0, rot, h0 = ego_rotation(frame)
    rel, dh, speed, present = history.track(rows, p0, h0)
    _fill(obs, rel @ rot.T, obs_range, speed, np.cos(dh), np.sin(dh), present, rows, frame.length, frame.width,
          frame.agent_type)
    return obs, rows[1:]


def forecast_observation(history: History, near: np.ndarray, predictor: Predictor, k: int, ff: int,
                         obs_range: float, dt: float) -> np.ndarray:
    """(K, Ff, 3) float32: present, x / range, y / range of each observed neighbour's forecast (rows `near` of
    the newest frame, in observation order) over Ff frames, in the ego's frame now; zeros where none."""
    fc = np.zeros((k, ff, 3), np.float32)
    frame = history.now
    if frame.ego < 0 or near.size == 0:
        return fc
    scene = scene_from_frames(history.frames, dt)
    order = np.argsort(scene.agent_id, kind="stable")
    targets = order[np.searchsorted(scene.agent_id[order], frame.agent_id[near])]  # scene rows of the neighbours
    forecast = predictor.predict(scene, targets, ff)
    p0, rot, _ = ego_rotation(frame)
    rel = (forecast.mean[:, :ff] - p0) @ rot.T / obs_range
    fc[: near.size, : rel.shape[1], 0] = 1.0
    fc[: near.size, : rel.shape[1], 1:] = np.clip(rel, -1.0, 1.0)
    return fc


@njit(cache=True)
def _clip(v: float) -> float:
    """v clipped to [-1, 1] as `np.clip` does it (NaN stays NaN)."""
    return -1.0 if v < -1.0 else (1.0 if v > 1.0 else v)


@njit(cache=True)
def _fill(obs: np.ndarray, pos: np.ndarray, obs_range: float, speed: np.ndarray, cos_dh: np.ndarray,
          sin_dh: np.ndarray, present: np.ndarray, rows: np.ndarray, length: np.ndarray, width: np.ndarray,
          agent_type: np.ndarray) -> None:
    """Write the features of m agents over t frames into obs[:m, H - t:] (right-aligned: the last column is
    now): each computed in float64, clipped to [-1, 1], times present (so absent entries are +-0), then cast
    to float32, as the numpy formulation it replaces did, in one pass instead of some twenty numpy calls.

    pos (m, t, 2) m: x, y in the ego frame, divided here by obs_range (m); speed (m, t) m/s; cos_dh, sin_dh
    (m, t): of the heading relative to the ego's now (numpy's values); present (m, t) bool; rows (m,): the agents'
    rows in the current frame, whose length, width (n,) m and agent_type (n,) they take.
    """
    m, t = present.shape
    h = obs.shape[1]
    for i in range(m):
        r = rows[i]
        if not 0 <= agent_type[r] < obs.shape[2] - 9:
            raise IndexError("agent_type out of range of AgentType")
        # float32 length / scale rounds alike through float64 (double rounding is exact for one division)
        lw0, lw1 = _clip(length[r] / LENGTH_SCALE), _clip(width[r] / WIDTH_SCALE)
        for j in range(t):
            p = 1.0 if present[i, j] else 0.0
            o = obs[i, h - t + j]
            o[0] = p
            o[1] = _clip(pos[i, j, 0] / obs_range) * p
            o[2] = _clip(pos[i, j, 1] / obs_range) * p
            o[3] = _clip(speed[i, j] * cos_dh[i, j] / SPEED_SCALE) * p  # velocity in the ego frame
            o[4] = _clip(speed[i, j] * sin_dh[i, j] / SPEED_SCALE) * p
            o[5] = _clip(cos_dh[i, j]) * p
            o[6] = _clip(sin_dh[i, j]) * p
            o[7] = lw0 * p
            o[8] = lw1 * p
            o[9 + agent_type[r]] = p  # one-hot AgentType (the rest stays zero)
