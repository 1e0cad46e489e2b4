"""`DenseTrafficEnv` and its two registered ids: drive the ego through dense mixed traffic.

Spaces, reward and episode rules are described in the package docstring (`simharness.envs`) and in
docs/planners.md. SUMO runs in a worker process per env (`SumoProcess`), so any number of
SumoDense-v0 envs live side by side in one process.
"""

from __future__ import annotations

import collections
import os
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from simharness.envs.actions import action_space, action_to_command
from simharness.envs.config import DEFAULT_CONFIG, resolve_config
from simharness.envs.observation import FEATURES, History, agents_observation, ego_offsets, forecast_observation
from simharness.envs.reward import (
    FAULT_FRAMES,
    GAP_CAP,
    TTC_CAP,
    ego_fault,
    ego_motion,
    ego_on_road,
    ego_safety,
    step_reward,
)
from simharness.errors import SimulatorError, UserError
from simharness.scenario import ScenarioSpec, load_scenario
from simharness.sim.base import EgoCommand

__all__ = ["DenseTrafficEnv", "HighwayDenseEnv", "SumoDenseEnv", "action_to_command"]


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class DenseTrafficEnv(gym.Env):
    """Base of both envs: wraps any `Simulator` built from a scenario with its ego enabled."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 5}
    default_scenario = "sumo_arterial_dense"
    worker_process = False  # run the simulator in a worker process (SUMO: libsumo holds one per process)

    def __init__(self, config: dict[str, Any] | None = None, render_mode: str | None = None) -> None:
        name = type(self).__name__
        self.config = resolve_config(self.default_config(), config, name)
        if render_mode not in (None, "rgb_array", "human"):
            raise UserError(f"{name}: render_mode {render_mode!r}: expected None, 'rgb_array' or 'human'")
        if render_mode == "human" and not _has_display():
            raise UserError(f"{name}: render_mode 'human' needs a display (DISPLAY is not set); use 'rgb_array' "
                            "and save or show the frames yourself")
        if not _has_display():  # an instance lists the modes it can show (env checkers build every listed mode)
            self.metadata = {**self.metadata, "render_modes": ["rgb_array"]}
        self.render_mode = render_mode
        self.spec_ = self._scenario_spec()
        c = self.config
        h = int(c["history_frames"])
        self.observation_space = observation_space(c)
        self.action_space = action_space(c)
        self._episode_steps = max(1, int(round(float(c["duration"]) / self.spec_.dt)))
        target = c["target_speed"] if c["target_speed"] is not None else self.spec_.road.speed_limit
        self._target_step = float(target) * self.spec_.dt  # m per step at which the progress term is full
        self._sim = None
        self._predictor = None
        self._history = History(h)
        self._recent: collections.deque = collections.deque(maxlen=FAULT_FRAMES)  # for the fault judgement
        self._window = None  # the human render mode's figure
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
        self._recent.clear()
        self._history.append(frame)
        self._recent.append(frame)
        ego_frames = int(frame.ego >= 0)
        for _ in range(h + 50):  # let the ego in and build up its history under the simulator's own model
            if frame.ego >= 0 and ego_frames >= h:
                break
            frame = self._sim.step(None)
            self._history.append(frame)
            self._recent.append(frame)
            ego_frames = ego_frames + 1 if frame.ego >= 0 else 0
        if frame.ego < 0 or ego_frames < h:
            raise SimulatorError(f"{self.spec_.name}: the ego did not enter the road within {h + 50} frames")
        prev = self._history.frames[-2]
        self._prev_acc = (float(frame.speed[frame.ego]) - float(prev.speed[prev.ego])) / self.spec_.dt
        self._steps = 0
        self._contact_prev = ego_safety(frame).contact  # an overlap the simulator placed is not new
        self._collisions = 0
        self._at_fault = 0
        self._progress = 0.0
        self._done = False
        obs, _ = self._observation()
        return obs, self._info(TTC_CAP, GAP_CAP)

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self._sim is None or self._done:
            raise RuntimeError(f"{type(self).__name__}.step: the episode is over or not started; call reset()")
        c = self.config
        command = self.command(action)
        prev = self._history.now
        frame = self._sim.step(command)
        self._history.append(frame)
        self._recent.append(frame)
        self._steps += 1
        if frame.ego < 0:  # the ego drove off the end of the road: done, nothing more to score
            self._done = True
            obs, _ = self._observation()
            return obs, 0.0, True, False, self._info(TTC_CAP, GAP_CAP)
        offsets = ego_offsets(frame)  # shared by the safety terms and the observation
        safe = ego_safety(frame, offsets)
        obs, near = self._observation(offsets[2])
        motion = ego_motion(prev, frame, near, self.spec_.dt, self._prev_acc)
        self._prev_acc = motion.accel
        self._progress += motion.moved
        new_contact = safe.contact and not self._contact_prev
        self._contact_prev = safe.contact
        collision = None
        if new_contact:
            at_fault = ego_fault(list(self._recent), self.spec_.dt)
            collision = "at_fault" if at_fault else "hit"
            self._collisions += 1
            self._at_fault += int(at_fault)
        on_road = ego_on_road(frame, self._sim.road)
        reward = step_reward(c["reward"], motion, self._target_step, float(c["max_lateral_speed"]), on_road,
                             collision, self._episode_steps, safe.ttc)
        terminated = bool(new_contact and c["terminate_on_collision"])
        truncated = not terminated and self._steps >= self._episode_steps
        self._done = terminated or truncated
        return obs, float(reward), terminated, bool(truncated), self._info(safe.ttc, safe.gap, on_road)

    def command(self, action: Any) -> EgoCommand:
        """An action -> physical `EgoCommand` (`simharness.envs.actions`); ValueError for NaN, inf or a bad index."""
        frame = self._history.now if len(self._history) else None  # the meta-actions steer from the present
        return action_to_command(action, self.config, type(self).__name__, frame)

    def render(self) -> np.ndarray | None:
        """rgb_array: (H, W, 3) uint8 top-down view around the ego (`simharness.envs.render`); human: shown in a
        window; None without a render mode."""
        if self.render_mode is None:
            return None
        from simharness.envs.render import render_frame

        img = render_frame(self._history.now, self._sim.road if self._sim is not None else None,
                           title=f"{getattr(self.spec, 'id', None) or type(self).__name__}  "
                                 f"t = {self._steps * self.spec_.dt:.1f} s")
        if self.render_mode == "rgb_array":
            return img
        import matplotlib.pyplot as plt

        if self._window is None:
            self._window = plt.imshow(img)
            plt.axis("off")
        else:
            self._window.set_data(img)
        plt.pause(1.0 / self.metadata["render_fps"])
        return None

    def close(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None
        self._done = True

    # ------------------------------------------------------------------ pieces
    def _info(self, ttc: float, gap: float, on_road: bool = True) -> dict[str, Any]:
        f = self._history.now
        return {"t": float(f.t), "speed": float(f.speed[f.ego]) if f.ego >= 0 else 0.0,
                "progress_m": float(self._progress), "collided": bool(self._collisions > 0),
                "collisions": int(self._collisions), "at_fault_collisions": int(self._at_fault),
                "on_road": bool(on_road), "min_ttc": float(min(ttc, TTC_CAP)), "min_gap": float(min(gap, GAP_CAP))}

    def _observation(self, d: np.ndarray | None = None) -> tuple[Any, np.ndarray]:
        """(The observation now, the rows of its neighbours in the current frame); d (n,) m: the current frame's
        distances to the ego (`ego_offsets`), if known."""
        c = self.config
        k, h, rng = int(c["num_agents"]), int(c["history_frames"]), float(c["obs_range"])
        obs, near = agents_observation(self._history, k, h, rng, d)
        if c["flatten"]:
            obs = obs.reshape(-1)
        if not c["predictor"]:
            return obs, near
        fc = forecast_observation(self._history, near, self._predictor, k, int(c["forecast_frames"]), rng,
                                  self.spec_.dt)
        return {"agents": obs, "forecast": fc.reshape(-1) if c["flatten"] else fc}, near


def observation_space(config: dict[str, Any]) -> spaces.Space:
    """The env's observation space under `config` (the package docstring): a Box, or a Dict with "forecast"."""
    k, h = int(config["num_agents"]), int(config["history_frames"])
    shape = (k + 1, h, FEATURES)
    fshape = (k, int(config["forecast_frames"]), 3)
    if config["flatten"]:
        shape, fshape = (int(np.prod(shape)),), (int(np.prod(fshape)),)
    agents = spaces.Box(-1.0, 1.0, shape, np.float32)
    if not config["predictor"]:
        return agents
    return spaces.Dict({"agents": agents, "forecast": spaces.Box(-1.0, 1.0, fshape, np.float32)})


class SumoDenseEnv(DenseTrafficEnv):
    """`simharness/SumoDense-v0`: the SUMO dense arterial (libsumo in a worker process per env)."""

    default_scenario = "sumo_arterial_dense"
    worker_process = True


class HighwayDenseEnv(DenseTrafficEnv):
    """`simharness/HighwayDense-v0`: the highway-env mixed dense scenario."""

    default_scenario = "highway_mixed_dense"
