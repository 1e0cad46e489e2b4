"""Gymnasium environments over the harness's scenarios: drive the ego through dense mixed traffic.

`import simharness.envs` registers

- ``simharness/SumoDense-v0``: the SUMO dense arterial (libsumo: one env per process; use
  `AsyncVectorEnv` for several);
- ``simharness/HighwayDense-v0``: the highway-env mixed dense scenario (`SyncVectorEnv` or
  `AsyncVectorEnv`).

In a fresh process (e.g. an `AsyncVectorEnv` worker started by "spawn") use
``gymnasium.make("simharness.envs:simharness/SumoDense-v0")``, which imports this module first.

Configuration: ``gymnasium.make(id, config={...})``; keys and defaults in `DEFAULT_CONFIG`
(like highway-env's ``default_config()``); unknown keys are refused.

Observation (``Box(-1, 1, (K + 1, H, F))`` float32): the ego (row 0) and its K nearest agents
(rows 1..K, nearest first) over the last H frames, in the ego's frame at the current step (x ahead,
y left), features ``present, x / range, y / range, vx / 30, vy / 30, cos(dh), sin(dh), length / 15,
width / 3`` and a one-hot `AgentType` (9), all clipped to [-1, 1]; ``present`` (feature 0) is the
mask: absent rows and frames are zero. With ``config["predictor"]`` set the observation is a Dict
``{"agents": that Box, "forecast": Box(-1, 1, (K, Ff, 3))}`` with each neighbour's forecast
positions (present, x / range, y / range) over Ff frames from that predictor.

Action (``Box(-1, 1, (2,))`` float32, normalised as RL libraries prefer): ``a[0]`` longitudinal
acceleration, ``a[0] * max_accel`` when positive and ``a[0] * max_decel`` when negative (m/s^2);
``a[1] * max_lateral_speed`` lateral velocity (m/s, + left); held for the next frame.
`DenseTrafficEnv.command(action)` gives the physical `EgoCommand`.

Reward per step (weights in ``config["reward"]``): ``progress * metres made good along the ego's
heading + collision * (1 on the first frame of each new ego contact) + accel * a^2 + jerk * (da/dt)^2
+ lateral * v_lat^2`` (the comfort weights are negative). An episode terminates on a collision (if
``terminate_on_collision``) or when the ego leaves the road, and is truncated after ``duration`` s.

``info`` holds fixed-shape scalars only (vector envs stack them): ``t``, ``speed``, ``progress_m``,
``collided``, ``collisions``, ``min_ttc`` (s, capped at 10), ``min_gap`` (m, capped at 100).
"""

from __future__ import annotations

import copy
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from simharness.errors import UserError
from simharness.metrics import safety
from simharness.scenario import ScenarioSpec, load_scenario
from simharness.scene import AgentType, Scene
from simharness.sim.base import EgoCommand, Frame, scene_from_frames

DEFAULT_CONFIG: dict[str, Any] = {
    "scenario": None,  # scenario file or shipped name; each env id sets its own default
    "overrides": {},  # dotted scenario keys, e.g. {"demand_scale": 0.5}
    "reaction": None,  # reactive | cut_in | ignore; None keeps the scenario's
    "duration": 20.0,  # seconds of driving per episode
    "warmup": None,  # override the scenario's warm-up (s); None keeps it
    "num_agents": 16,  # K nearest agents observed
    "history_frames": 5,  # H frames of history per agent
    "obs_range": 60.0,  # m: positions are divided by this; agents farther away are not observed
    "predictor": None,  # e.g. "const-vel" or "traphic": adds the "forecast" observation
    "forecast_frames": 10,  # Ff forecast frames in the observation
    "max_accel": 2.5,  # m/s^2
    "max_decel": 7.0,  # m/s^2
    "max_lateral_speed": 1.5,  # m/s
    "terminate_on_collision": True,
    "reward": {"progress": 0.1, "collision": -10.0, "accel": -0.01, "jerk": -0.0005, "lateral": -0.01},
}
FEATURES = 9 + len(AgentType)


class DenseTrafficEnv(gym.Env):
    """Base of both envs: wraps any `Simulator` built from a scenario with its ego enabled."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}
    default_scenario = "sumo_arterial_dense"

    def __init__(self, config: dict[str, Any] | None = None, render_mode: str | None = None) -> None:
        self.config = self.default_config()
        for key, value in (config or {}).items():
            if key not in self.config:
                raise UserError(f"{type(self).__name__} config: unknown key {key!r}; expected one of "
                                f"{', '.join(sorted(self.config))}")
            self.config[key] = {**self.config[key], **value} if key == "reward" else value
        if render_mode not in (None, "rgb_array"):
            raise UserError(f"render_mode {render_mode!r}: expected None or 'rgb_array'")
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
        self._frames: list[Frame] = []

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        """A fresh copy of the defaults (see the module docstring), with this env's scenario."""
        config = copy.deepcopy(DEFAULT_CONFIG)
        config["scenario"] = cls.default_scenario
        return config

    def _scenario_spec(self) -> ScenarioSpec:
        c = self.config
        spec = load_scenario(c["scenario"])
        changes = {**c["overrides"], "ego.enabled": True, "ego.insert_at": 0.0,
                   "duration": float(c["duration"]) + (int(c["history_frames"]) + 2) / spec.record_hz}
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
            self._sim = make_simulator(self.spec_)
        if self.config["predictor"] and self._predictor is None:
            from simharness.predictors import load_predictor

            self._predictor = load_predictor(self.config["predictor"])
        sim_seed = int(self.np_random.integers(0, 2**31 - 1 - self.spec_.seed))
        self._frames = [self._sim.reset(sim_seed)]
        # Let the ego in and build up its history under the simulator's own model.
        for _ in range(int(self.config["history_frames"]) + 1):
            if self._frames[-1].ego >= 0 and sum(f.ego >= 0 for f in self._frames) >= self.config["history_frames"]:
                break
            self._frames.append(self._sim.step(None))
        if self._frames[-1].ego < 0:
            raise RuntimeError(f"{self.spec_.name}: the ego was not inserted (seed {sim_seed})")
        self._steps = 0
        self._prev_acc = 0.0
        self._contact_prev = False
        self._collisions = 0
        self._progress = 0.0
        return self._observation(), self._info(np.inf, np.inf)

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self._sim is None or not self._frames:
            raise RuntimeError("call reset() before step()")
        c, w = self.config, self.config["reward"]
        command = self.command(action)
        a = (command.acceleration, command.lateral_velocity)
        prev = self._frames[-1]
        frame = self._sim.step(command)
        self._frames.append(frame)
        self._frames = self._frames[-(int(c["history_frames"]) + 2):]
        dt = self.spec_.dt
        if frame.ego < 0:  # the ego drove off the end of the road: done, nothing more to score
            self._steps += 1
            return self._observation(), 0.0, True, False, self._info(np.inf, np.inf)
        step = frame.xy[frame.ego] - prev.xy[prev.ego] if prev.ego >= 0 else np.zeros(2)
        h = prev.heading[prev.ego] if prev.ego >= 0 else frame.heading[frame.ego]
        moved = float(step[0] * np.cos(h) + step[1] * np.sin(h))
        self._progress += moved
        contact, ttc, gap = self._safety(frame)
        new_contact = contact and not self._contact_prev
        self._contact_prev = contact
        self._collisions += int(new_contact)
        reward = (w["progress"] * moved + w["collision"] * float(new_contact) + w["accel"] * a[0] ** 2
                  + w["jerk"] * ((a[0] - self._prev_acc) / dt) ** 2 + w["lateral"] * a[1] ** 2)
        self._prev_acc = float(a[0])
        terminated = bool(new_contact and c["terminate_on_collision"])
        self._steps += 1
        truncated = self._steps * dt >= float(c["duration"]) - 1e-9
        return self._observation(), float(reward), terminated, bool(truncated and not terminated), \
            self._info(ttc, gap)

    def command(self, action: np.ndarray) -> EgoCommand:
        """Normalised action (2,) in [-1, 1] -> physical `EgoCommand` (see the module docstring)."""
        c = self.config
        a = np.clip(np.asarray(action, np.float64).reshape(2), -1.0, 1.0)
        acc = a[0] * (c["max_accel"] if a[0] >= 0 else c["max_decel"])
        return EgoCommand(float(acc), float(a[1] * c["max_lateral_speed"]))

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._sim is not None and hasattr(self._sim, "render"):
            return self._sim.render()
        return _render_frame(self._frames[-1], self._sim.road if self._sim is not None else None)

    def close(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None

    # ------------------------------------------------------------------ pieces
    def _scene(self) -> Scene:
        return scene_from_frames(self._frames[-int(self.config["history_frames"]):], self.spec_.dt)

    def _safety(self, frame: Frame) -> tuple[bool, float, float]:
        """(ego in contact now, min time-to-collision s, min gap m) from the current frame's boxes."""
        xy, hd = frame.xy[:, None].astype(np.float64), frame.heading[:, None]
        valid = np.ones((frame.num_agents, 1), bool)
        contact = safety.ego_contact(xy, hd, frame.length, frame.width, valid, frame.ego)
        vel = (frame.speed[:, None] * np.stack([np.cos(frame.heading), np.sin(frame.heading)], -1))[:, None]
        ttc = safety.time_to_collision(xy, vel, hd, frame.length, frame.width, valid, frame.ego, horizon=3.0)
        gap = safety.min_gap(xy, hd, frame.length, frame.width, valid, frame.ego)
        return bool(contact.any()), float(ttc.min()), float(gap.min())

    def _info(self, ttc: float, gap: float) -> dict[str, Any]:
        f = self._frames[-1]
        return {"t": float(f.t), "speed": float(f.speed[f.ego]) if f.ego >= 0 else 0.0,
                "progress_m": float(self._progress), "collided": bool(self._collisions > 0),
                "collisions": int(self._collisions), "min_ttc": float(min(ttc, 10.0)),
                "min_gap": float(min(gap, 100.0))}

    def _observation(self) -> Any:
        c = self.config
        k, h, rng = int(c["num_agents"]), int(c["history_frames"]), float(c["obs_range"])
        obs = np.zeros((k + 1, h, FEATURES), np.float32)
        scene = self._scene()
        e = scene.ego
        if e < 0:
            return self._wrap(obs, None, None)
        p0 = scene.xy[e, -1].astype(np.float64)
        h0 = float(scene.heading[e, -1])
        dist = np.linalg.norm(scene.xy[:, -1] - p0, axis=-1)
        cand = np.flatnonzero(scene.valid[:, -1] & (dist <= rng) & (np.arange(scene.num_agents) != e))
        near = cand[np.argsort(dist[cand], kind="stable")][:k]
        rows = np.concatenate([[e], near]).astype(int)
        m, t = rows.size, scene.num_frames
        rot = np.array([[np.cos(h0), np.sin(h0)], [-np.sin(h0), np.cos(h0)]])  # world -> ego frame
        rel = (scene.xy[rows] - p0) @ rot.T  # (m, T, 2)
        vel = scene.speed[rows][..., None] * np.stack([np.cos(scene.heading[rows]), np.sin(scene.heading[rows])], -1)
        vrel = vel @ rot.T
        dh = scene.heading[rows] - h0
        onehot = np.eye(len(AgentType), dtype=np.float32)[scene.agent_type[rows]]  # (m, 9)
        feats = np.concatenate([
            np.ones((m, t, 1)), rel / rng, vrel / 30.0, np.cos(dh)[..., None], np.sin(dh)[..., None],
            np.broadcast_to((scene.length[rows] / 15.0)[:, None, None], (m, t, 1)),
            np.broadcast_to((scene.width[rows] / 3.0)[:, None, None], (m, t, 1)),
            np.broadcast_to(onehot[:, None], (m, t, len(AgentType)))], -1)
        feats = np.where(scene.valid[rows][..., None], np.clip(feats, -1.0, 1.0), 0.0)
        obs[:m, h - t:] = feats  # right-aligned: the last column is now
        return self._wrap(obs, scene, near)

    def _wrap(self, obs: np.ndarray, scene: Scene | None, near: np.ndarray | None) -> Any:
        c = self.config
        if not c["predictor"]:
            return obs
        k, ff, rng = int(c["num_agents"]), int(c["forecast_frames"]), float(c["obs_range"])
        fc = np.zeros((k, ff, 3), np.float32)
        if scene is not None and near is not None and near.size and self._predictor is not None:
            e = scene.ego
            forecast = self._predictor.predict(scene, near, ff)
            p0, h0 = scene.xy[e, -1].astype(np.float64), float(scene.heading[e, -1])
            rot = np.array([[np.cos(h0), np.sin(h0)], [-np.sin(h0), np.cos(h0)]])
            rel = (forecast.mean[:, :ff] - p0) @ rot.T / rng
            fc[: near.size, : rel.shape[1], 0] = 1.0
            fc[: near.size, : rel.shape[1], 1:] = np.clip(rel, -1.0, 1.0)
        return {"agents": obs, "forecast": fc}


class SumoDenseEnv(DenseTrafficEnv):
    """`simharness/SumoDense-v0`: the SUMO dense arterial (one per process: libsumo)."""

    default_scenario = "sumo_arterial_dense"


class HighwayDenseEnv(DenseTrafficEnv):
    """`simharness/HighwayDense-v0`: the highway-env mixed dense scenario."""

    default_scenario = "highway_mixed_dense"


def _render_frame(frame: Frame, road: Any, view: float = 40.0) -> np.ndarray:
    """Top-down RGB image (H, W, 3) uint8 of one frame around the ego (for backends without `render`)."""
    import matplotlib.pyplot as plt

    from simharness.report import draw_agents, draw_road

    fig, ax = plt.subplots(figsize=(6, 2.4), dpi=80)
    draw_road(ax, road)
    draw_agents(ax, frame.xy, frame.heading, frame.length, frame.width, frame.agent_type, ego=frame.ego)
    cx, cy = frame.xy[frame.ego] if frame.ego >= 0 else frame.xy.mean(0)
    ax.set_xlim(cx - view, cx + view)
    ax.set_ylim(cy - view * 0.4, cy + view * 0.4)
    ax.set_aspect("equal")
    ax.axis("off")
    fig.tight_layout(pad=0)
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return img


def _register() -> None:
    for env_id, cls in (("simharness/SumoDense-v0", "SumoDenseEnv"), ("simharness/HighwayDense-v0", "HighwayDenseEnv")):
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=f"simharness.envs:{cls}")


_register()
