"""Replay backend: a recorded data set as a scenario (`backend = "replay"`); follows `sim.base.Simulator`.

`reset(seed)` picks a scene and one of its agents by seed (`recording.choose_ego`); the episode starts at that
agent's first frame and the harness drives it from then on. The ego moves along its own recorded path (its
route): the command's acceleration sets its speed along the path and its lateral velocity an offset from it
(metres, + left), so `sim_heading` is the path's tangent. With no command the ego replays its recording.
Everyone else, by `replay.mode`:
- `log`: replays the recording exactly; their future does not depend on the ego (Waymax's log playback);
- `reactive`: follows their recorded paths with an IDM-style speed control that keeps a gap to the ego and to
  each other (`reactive`), and is exactly on the recording wherever nothing holds it back.
Frames are the recording's, subsampled to `record_hz` (which must divide the recording's rate). Past the end
of the recording the others are gone; the ego drives on along its path's last direction.
"""

from __future__ import annotations

import copy
import functools
import math
from pathlib import Path
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.scenario import ScenarioSpec
from simharness.sim.base import EgoCommand, Frame, RoadGeometry
from simharness.sim.replay.reactive import MAX_DECEL, ReactiveState, a_max_of, idm_accel, track_accel
from simharness.sim.replay.recording import Recording, choose_ego
from simharness.sim.replay.routes import Routes

EGO_ACCEL = (-8.0, 4.0)  # m/s^2: what the ego's command is clipped to
EGO_LATERAL_SPEED = 2.0  # m/s
SUBSTEP = 0.2  # s: longest reactive integration step (the harness's 5 Hz frames take one)


def data_path(spec: ScenarioSpec) -> Path:
    """The data set folder a replay scenario names, relative to its scenario file."""
    p = Path(spec.data)
    if not p.is_absolute() and spec.path and Path(spec.path).suffix == ".toml":
        p = Path(spec.path).parent / p
    return p


@functools.lru_cache(maxsize=4)
def _recording(path: str, pixel_scale: float) -> Recording:
    return Recording.load(path, pixel_scale)


class ReplaySimulator:
    """One replay episode of a recorded data set (module docstring)."""

    def __init__(self, spec: ScenarioSpec) -> None:
        self.spec = spec
        self.dt = spec.dt
        self.mode = spec.replay.mode
        self.recording = _recording(str(data_path(spec).resolve()), float(spec.replay.pixel_scale))
        self.road = RoadGeometry()
        self.k = 0

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int) -> Frame:
        """Pick the scene and the ego by seed; the episode's frame t = 0 is the ego's first recorded frame."""
        spec = self.spec
        scene0 = self.recording.scenes[0]
        stride = spec.dt / scene0.dt
        if abs(stride - round(stride)) > 1e-6 or round(stride) < 1:
            raise UserError(f"{spec.path or spec.name}: key 'record_hz': {spec.record_hz:g} Hz must divide the "
                            f"recording's {1 / scene0.dt:g} Hz")
        stride = int(round(stride))
        index, row = choose_ego(self.recording, spec.seed + int(seed), (spec.num_frames - 1) * stride + 1,
                                spec.replay.edge_margin)
        scene = self.recording.scenes[index]
        first = int(np.argmax(scene.valid[row]))
        self.scene = scene.slice_frames(first)  # views; subsampled below
        cols = np.arange(0, self.scene.num_frames, stride)
        sc = self.scene
        self.xy, self.heading, self.speed = sc.xy[:, cols], sc.heading[:, cols], sc.speed[:, cols]
        self.valid = sc.valid[:, cols]
        self.road = self.recording.roads[index]
        self.ego = row
        self.scene_id = str(scene.meta.get("scene_id", index))
        self.routes = Routes.from_tracks(self.xy, self.valid, self.heading, self.dt)
        self.k = 0
        self.ego_s, self.ego_v = float(self.routes.s_log[row, 0]), float(self.routes.v_log[row, 0])
        self.ego_lat, self.ego_lat_v = 0.0, 0.0
        n = len(self.valid)
        self._first = np.where(self.valid.any(1), np.argmax(self.valid, 1), self.valid.shape[1])
        self._last = self.valid.shape[1] - 1 - np.argmax(self.valid[:, ::-1], 1)
        self._s_track, self._v_track = self._tracks()
        self.state = ReactiveState(s=np.nan_to_num(self.routes.s_log[:, 0]), v=np.nan_to_num(self.routes.v_log[:, 0]),
                                   on_log=np.ones(n, bool))
        return self._frame()

    def _tracks(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, T) recorded arc length and speed, continued past each track's end at its last speed (what a held-back
        agent catches up with); nan before a track starts."""
        s, v = self.routes.s_log.copy(), self.routes.v_log.copy()
        n, t = s.shape
        rows = np.arange(n)
        last = self._last
        v_end = v[rows, last]
        after = np.arange(t)[None] > last[:, None]
        s = np.where(after, s[rows, last][:, None] + v_end[:, None] * (np.arange(t)[None] - last[:, None]) * self.dt, s)
        v = np.where(after, v_end[:, None], v)
        return s, v

    def step(self, ego_command: EgoCommand | None = None) -> Frame:
        """Advance one recorded frame: the ego by the command (None: its recording), the others by the mode."""
        self._step_ego(ego_command)
        if self.mode == "reactive":
            self._step_reactive()
        self.k += 1
        return self._frame()

    def _step_ego(self, command: EgoCommand | None) -> None:
        k, e, dt = self.k, self.ego, self.dt
        if command is None:
            s_next = self._log(self._s_track[e], k + 1)
            self.ego_v = float(self._log(self._v_track[e], k + 1))
            self.ego_s = float(s_next)
            self.ego_lat_v = 0.0
            return
        a = float(np.clip(command.acceleration, *EGO_ACCEL))
        v_new = max(self.ego_v + a * dt, 0.0)
        self.ego_s += 0.5 * (self.ego_v + v_new) * dt
        self.ego_v = v_new
        self.ego_lat_v = float(np.clip(command.lateral_velocity, -EGO_LATERAL_SPEED, EGO_LATERAL_SPEED))
        self.ego_lat += self.ego_lat_v * dt

    def _log(self, row: np.ndarray, k: int) -> float:
        """A (T,) recorded series at frame k, continued at its last value past the recording's end."""
        return row[min(k, len(row) - 1)]

    def _step_reactive(self) -> None:
        """The others from frame k to k + 1, in substeps of at most SUBSTEP s (module `reactive`)."""
        st, k, t = self.state, self.k, self.valid.shape[1]
        n_sub = max(1, math.ceil(self.dt / SUBSTEP - 1e-9))
        h = self.dt / n_sub
        k1 = min(k + 1, t - 1)
        entering = self._first == k + 1
        for i in range(n_sub):
            w = (i + 1) / n_sub
            s_log = (1 - w) * self._s_track[:, min(k, t - 1)] + w * self._s_track[:, k1]
            v_log = (1 - w) * self._v_track[:, min(k, t - 1)] + w * self._v_track[:, k1]
            alive = self._alive(k) & ~entering
            xy, heading, speed = self._others_now(alive)
            leaders = alive & ~st.on_log
            leaders[self.ego] = self._ego_off_log()
            a_idm = idm_accel(xy, heading, speed, self.scene.length, self.scene.width, self.scene.agent_type, alive,
                              leaders, self.ego)
            need = (v_log - st.v) / h
            keep = st.on_log & (a_idm >= need) & alive
            a = np.clip(np.minimum(track_accel(st, s_log, v_log), a_idm), -MAX_DECEL, a_max_of(self.scene.agent_type))
            v_new = np.maximum(st.v + a * h, 0.0)
            s_new = st.s + 0.5 * (st.v + v_new) * h
            st.s = np.where(keep, s_log, np.where(alive, s_new, st.s))
            st.v = np.where(keep, v_log, np.where(alive, v_new, st.v))
            st.on_log = keep | (alive & (np.abs(st.s - s_log) < 0.05) & (np.abs(st.v - v_log) < 0.1))
        # Agents entering now start on their recording.
        st.s = np.where(entering, np.nan_to_num(self.routes.s_log[:, k1]), st.s)
        st.v = np.where(entering, np.nan_to_num(self.routes.v_log[:, k1]), st.v)
        st.on_log |= entering

    def _ego_off_log(self) -> bool:
        """Whether the ego has left its recording: more than 0.2 m behind it, or more than 0.1 m beside its path."""
        behind = self._log(self._s_track[self.ego], self.k) - self.ego_s > 0.2
        return bool(behind or abs(self.ego_lat) > 0.1)

    def _alive(self, k: int) -> np.ndarray:
        """(N,) agents in the reactive world at frame k: entered, and not yet past both their recording and path."""
        s_end = self.routes.s[np.arange(len(self.valid)), self.routes.count - 1]
        alive = (self._first <= k) & ((k <= self._last) | (~self.state.on_log & (self.state.s < s_end - 1e-6)))
        alive[self.ego] = False
        return alive

    def _others_now(self, alive: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions (N, 2), headings (N,), speeds (N,) of the reactive world now, the ego's row its own."""
        n = len(self.valid)
        xy = np.zeros((n, 2))
        heading = np.zeros(n)
        speed = self.state.v.copy()
        # Agents on their recording are where it has them (positions, headings and speeds as recorded) ...
        kk = min(self.k, self.valid.shape[1] - 1)
        logged = alive & self.state.on_log & self.valid[:, kk]
        xy[logged], heading[logged], speed[logged] = (self.xy[logged, kk], self.heading[logged, kk],
                                                      self.speed[logged, kk])
        # ... the others on their paths.
        rows = np.flatnonzero(alive & ~logged)
        if rows.size:
            xy[rows], heading[rows] = self.routes.at(rows, self.state.s[rows])
        exy, eh, _ = self._ego_pose()
        xy[self.ego], heading[self.ego], speed[self.ego] = exy, eh, self.ego_v
        return xy, heading, speed

    def _ego_pose(self) -> tuple[np.ndarray, float, float]:
        """The ego's centre (2,), body heading and path tangent (rad)."""
        p, tangent = self.routes.at(np.array([self.ego]), np.array([self.ego_s]))
        tan = float(tangent[0])
        xy = p[0] + self.ego_lat * np.array([-math.sin(tan), math.cos(tan)])
        return xy, tan + math.atan2(self.ego_lat_v, max(self.ego_v, 1e-3)), tan

    # ------------------------------------------------------------------ output
    def _frame(self) -> Frame:
        k, t, e = self.k, self.valid.shape[1], self.ego
        if self.mode == "reactive" and k > 0:
            present = self._alive(k)
            xy, heading, speed = self._others_now(present)
        else:
            kk = min(k, t - 1)
            present = self.valid[:, kk] & (k < t)
            xy, heading, speed = (self.xy[:, kk].astype(np.float64), self.heading[:, kk].astype(np.float64),
                                  self.speed[:, kk].astype(np.float64))
        present = present.copy()
        present[e] = True
        exy, eh, tan = self._ego_pose()
        xy, heading, speed = xy.copy(), heading.copy(), speed.copy()
        xy[e], heading[e], speed[e] = exy, eh, math.hypot(self.ego_v, self.ego_lat_v)
        sim_heading = heading.copy()
        sim_heading[e] = tan
        rows = np.flatnonzero(present)
        sc = self.scene
        return Frame(
            t=round(k * self.dt, 9), agent_id=sc.agent_id[rows], agent_type=sc.agent_type[rows],
            xy=xy[rows].astype(np.float32), heading=heading[rows].astype(np.float32),
            speed=speed[rows].astype(np.float32), length=sc.length[rows], width=sc.width[rows],
            ego=int(np.flatnonzero(rows == e)[0]),
            extra={"sim_heading": sim_heading[rows].astype(np.float32)},
        )

    def branch(self) -> ReplaySimulator:
        """An independent copy of the running episode (the recording shared, the state copied)."""
        other = copy.copy(self)
        other.state = copy.deepcopy(self.state)
        return other

    def meta(self) -> dict[str, Any]:
        """What a Scene's meta should record about this run."""
        return {"backend": "replay", "replay_mode": self.mode, "replay_scene": self.scene_id,
                "replay_agent": str(self.scene.agent_id[self.ego]), "data": self.recording.source}

    def close(self) -> None:
        """Nothing to release (the recording stays cached for the next episode in this process)."""
