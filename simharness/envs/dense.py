"""`DenseTrafficEnv` and its two registered ids: drive the ego through dense mixed traffic.

Spaces, reward and episode rules are described in the package docstring (`simharness.envs`) and in
docs/planners.md. SUMO runs in a worker process per env (`SumoProcess`), so any number of
SumoDense-v0 envs live side by side in one process.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from simharness.envs.config import DEFAULT_CONFIG, resolve_config
from simharness.envs.observation import FEATURES, History, agents_observation, ego_offsets, ego_rotation
from simharness.envs.reward import GAP_CAP, TTC_CAP, ego_safety, step_reward
from simharness.errors import SimulatorError
from simharness.scenario import ScenarioSpec, load_scenario
from simharness.sim.base import EgoCommand, Frame, scene_from_frames


class DenseTrafficEnv(gym.Env):
    """Base of both envs: wraps any `Simulator` built from a scenario with its ego enabled."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}
    default_scenario = "sumo_arterial_dense"
    worker_process = False  # run the simulator in a worker process (SUMO: libsumo holds one per process)

    def __init__(self, config: dict[str, Any] | None = None, render_mode: str | None = None) -> None:
        name = type(self).__name__
        self.config = resolve_config(self.default_config(), config, name)
        if render_mode not in (None, "rgb_array"):
            from simharness.errors import UserError

            raise UserError(f"{name}: render_mode {render_mode!r}: expected None or 'rgb_array'")
        self.render_mode = render_mode
        self.spec_ = self._scenario_spec()
        c = self.config
        k, h = int(c["num_agents"]), int(c["history_frames"])
        agents = spaces.Box(-1.0, 1.0, (k + 1, h, FEATURES), np.float32)
        if c["predictor"]:
            self.observation_space = spaces.Dict(
                {"agents": agents, "forecast": spaces.Box(-1.0, 1.0, (k, int(c["forecast_frames"]), 3), np.float32)})
        else:
            self.observation_space = agents
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._sim = None
        self._predictor = None
        self._history = History(h)
        self._done = True  # no episode yet: step() needs reset()
        self._episodes_in_sim = 0

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        """A fresh copy of the defaults (config.DEFAULT_CONFIG), with this env's scenario."""
        import copy

        config = copy.deepcopy(DEFAULT_CONFIG)
        config["scenario"] = cls.default_scenario
        return config

    def _scenario_spec(self) -> ScenarioSpec:
        c = self.config
        spec = load_scenario(c["scenario"])
        episode = float(c["duration"]) + (int(c["history_frames"]) + 2) / spec.record_hz
        changes = {**c["overrides"], "ego.enabled": True, "ego.insert_at": 0.0,
                   "duration": episode * int(c["episodes_per_warmup"])}
        if c["reaction"] is not None:
            changes["ego.reaction"] = c["reaction"]
        if c["warmup"] is not None:
            changes["warmup"] = float(c["warmup"])
        return spec.with_overrides(changes)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        from simharness.sim import make_simulator

        if self._sim is None:
            self._sim = make_simulator(self.spec_, process=self.worker_process)
            self._episodes_in_sim = int(self.config["episodes_per_warmup"])  # nothing is running yet
        if self.config["predictor"] and self._predictor is None:
            from simharness.predictors import load_predictor

            self._predictor = load_predictor(self.config["predictor"])
        c = self.config
        h = int(c["history_frames"])
        frame = None
        if seed is None and self._episodes_in_sim < int(c["episodes_per_warmup"]):
            try:  # a warm reset: the same traffic runs on and the ego enters again
                frame = self._sim.restart_ego()
            except SimulatorError:
                frame = None
        if frame is None:
            sim_seed = int(self.np_random.integers(0, 2**31 - 1 - self.spec_.seed))
            frame = self._sim.reset(sim_seed)
            self._episodes_in_sim = 0
        self._episodes_in_sim += 1
        self._history.clear()
        self._history.append(frame)
        ego_frames = int(frame.ego >= 0)
        for _ in range(h + 50):  # let the ego in and build up its history under the simulator's own model
            if frame.ego >= 0 and ego_frames >= h:
                break
            frame = self._sim.step(None)
            self._history.append(frame)
            ego_frames = ego_frames + 1 if frame.ego >= 0 else 0
        if frame.ego < 0 or ego_frames < h:
            raise SimulatorError(f"{self.spec_.name}: the ego did not enter the road within {h + 50} frames")
        self._steps = 0
        self._prev_acc = 0.0
        self._contact_prev = False
        self._collisions = 0
        self._progress = 0.0
        self._done = False
        return self._observation(), self._info(TTC_CAP, GAP_CAP)

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self._sim is None or self._done:
            raise RuntimeError(f"{type(self).__name__}.step: the episode is over or not started; call reset()")
        c = self.config
        command = self.command(action)
        prev = self._history.now
        frame = self._sim.step(command)
        self._history.append(frame)
        self._steps += 1
        if frame.ego < 0:  # the ego drove off the end of the road: done, nothing more to score
            self._done = True
            return self._observation(), 0.0, True, False, self._info(TTC_CAP, GAP_CAP)
        if prev.ego >= 0:  # Python floats: the float64 arithmetic of numpy's, without its per-scalar overhead
            (x, y), (px, py) = frame.xy[frame.ego].tolist(), prev.xy[prev.ego].tolist()
            h = float(prev.heading[prev.ego])
            moved = (x - px) * float(np.cos(h)) + (y - py) * float(np.sin(h))
        else:
            moved = 0.0
        self._progress += moved
        offsets = ego_offsets(frame)  # shared by the safety terms and the observation
        safe = ego_safety(frame, offsets)
        new_contact = safe.contact and not self._contact_prev
        self._contact_prev = safe.contact
        self._collisions += int(new_contact)
        reward = step_reward(c["reward"], moved, new_contact, command.acceleration, self._prev_acc,
                             command.lateral_velocity, self.spec_.dt)
        self._prev_acc = float(command.acceleration)
        terminated = bool(new_contact and c["terminate_on_collision"])
        truncated = not terminated and self._steps * self.spec_.dt >= float(c["duration"]) - 1e-9
        self._done = terminated or truncated
        return (self._observation(offsets[2]), float(reward), terminated, bool(truncated),
                self._info(safe.ttc, safe.gap))

    def command(self, action: np.ndarray) -> EgoCommand:
        """Normalised action (2,) -> physical `EgoCommand`: clipped to [-1, 1]; NaN or inf raise ValueError."""
        return action_to_command(action, self.config, type(self).__name__)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._sim is not None and hasattr(self._sim, "render"):
            return self._sim.render()
        from simharness.envs.render import render_frame

        return render_frame(self._history.now, self._sim.road if self._sim is not None else None)

    def close(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None
        self._done = True

    # ------------------------------------------------------------------ pieces
    def _info(self, ttc: float, gap: float) -> dict[str, Any]:
        f = self._history.now
        return {"t": float(f.t), "speed": float(f.speed[f.ego]) if f.ego >= 0 else 0.0,
                "progress_m": float(self._progress), "collided": bool(self._collisions > 0),
                "collisions": int(self._collisions), "min_ttc": float(min(ttc, TTC_CAP)),
                "min_gap": float(min(gap, GAP_CAP))}

    def _observation(self, d: np.ndarray | None = None) -> Any:
        """The observation now; d (n,) m: the current frame's distances to the ego (`ego_offsets`), if known."""
        c = self.config
        k, h, rng = int(c["num_agents"]), int(c["history_frames"]), float(c["obs_range"])
        obs, near = agents_observation(self._history, k, h, rng, d)
        if not c["predictor"]:
            return obs
        return {"agents": obs, "forecast": self._forecast(self._history.now, near)}

    def _forecast(self, frame: Frame, near: np.ndarray) -> np.ndarray:
        """(K, Ff, 3): present, x / range, y / range of each observed neighbour's forecast, ego frame now."""
        c = self.config
        k, ff, rng = int(c["num_agents"]), int(c["forecast_frames"]), float(c["obs_range"])
        fc = np.zeros((k, ff, 3), np.float32)
        if frame.ego < 0 or near.size == 0 or self._predictor is None:
            return fc
        scene = scene_from_frames(self._history.frames, self.spec_.dt)
        order = np.argsort(scene.agent_id, kind="stable")
        targets = order[np.searchsorted(scene.agent_id[order], frame.agent_id[near])]  # scene rows of the neighbours
        forecast = self._predictor.predict(scene, targets, ff)
        p0, rot, _ = ego_rotation(frame)
        rel = (forecast.mean[:, :ff] - p0) @ rot.T / rng
        fc[: near.size, : rel.shape[1], 0] = 1.0
        fc[: near.size, : rel.shape[1], 1:] = np.clip(rel, -1.0, 1.0)
        return fc


def action_to_command(action: np.ndarray, config: dict[str, Any], where: str = "env") -> EgoCommand:
    """Normalised action (2,) -> `EgoCommand` (m/s^2, m/s) under `config`'s limits; see the package doc."""
    a = np.asarray(action, np.float64)
    if a.size != 2:
        raise ValueError(f"{where}: action of shape {a.shape}: expected 2 values (acceleration, lateral speed) "
                         "in [-1, 1]")
    acc, lat = a.ravel().tolist()  # Python floats: numpy's float64 values, without its per-scalar overhead
    if not (math.isfinite(acc) and math.isfinite(lat)):
        raise ValueError(f"{where}: action {[acc, lat]} is not finite; expected 2 values in [-1, 1] (larger "
                         "values are clipped, NaN and inf are refused)")
    acc, lat = min(max(acc, -1.0), 1.0), min(max(lat, -1.0), 1.0)
    acc = acc * (config["max_accel"] if acc >= 0 else config["max_decel"])
    return EgoCommand(float(acc), float(lat * config["max_lateral_speed"]))


class SumoDenseEnv(DenseTrafficEnv):
    """`simharness/SumoDense-v0`: the SUMO dense arterial (libsumo in a worker process per env)."""

    default_scenario = "sumo_arterial_dense"
    worker_process = True


class HighwayDenseEnv(DenseTrafficEnv):
    """`simharness/HighwayDense-v0`: the highway-env mixed dense scenario."""

    default_scenario = "highway_mixed_dense"
