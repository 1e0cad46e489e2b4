"""Gymnasium environments over the harness's scenarios: drive the ego through dense mixed traffic.

`import simharness.envs` registers

- ``simharness/SumoDense-v0``: the SUMO dense arterial; libsumo runs in a worker process per env
  (`simharness.sim.sumo.process.SumoProcess`), so any number live in one process (``gym.make`` twice,
  `SyncVectorEnv`, SB3's `DummyVecEnv` / `SubprocVecEnv`, `EvalCallback`);
- ``simharness/HighwayDense-v0``: the highway-env mixed dense scenario.

In a fresh process (e.g. an `AsyncVectorEnv` worker started by "spawn") use
``gymnasium.make("simharness.envs:simharness/SumoDense-v0")``, which imports this package first.

Configuration: ``gymnasium.make(id, config={...})``; keys and defaults in `DEFAULT_CONFIG`
(`simharness.envs.config`, like highway-env's ``default_config()``); unknown keys, non-finite and
out-of-range values are refused with one line (`UserError`).

Observation (`simharness.envs.observation`): the ego (row 0) and its K nearest agents (rows 1..K,
nearest first) over the last H frames, in the ego's frame at the current step (x ahead, y left),
features ``present, x / range, y / range, vx / 30, vy / 30, cos(dh), sin(dh), length / 15, width / 3``
and a one-hot `AgentType` (9), all clipped to [-1, 1]; ``present`` (feature 0) is the mask. By default
(``flatten``) a 1-D ``Box(-1, 1, ((K + 1) * H * F,))`` float32 (reshape to (K + 1, H, F)); with
``flatten = False`` the (K + 1, H, F) array. With ``config["predictor"]`` set the observation is a Dict
``{"agents": that Box, "forecast": Box(-1, 1, (K * Ff * 3,))}`` (or (K, Ff, 3)) with each neighbour's
forecast positions (present, x / range, y / range) over Ff frames from that predictor.

Action (`simharness.envs.actions`): ``config["action"] = "continuous"`` (default), ``Box(-1, 1, (2,))``:
acceleration ``a[0] * max_accel`` / ``a[0] * max_decel`` (m/s^2) and lateral velocity ``a[1] *
max_lateral_speed`` (m/s, + left); NaN or infinite values raise ValueError (nothing is stepped).
``"discrete"``: ``Discrete(12)`` meta-actions, {brake, slower, hold, faster} x {nudge left, straight,
nudge right}; ``"speed"``: ``Discrete(12)``, target speeds {stop, slow, cruise, fast} x the same nudges;
``"follow"``: the same, keeping IDM's gap to the agent ahead (the car-following given, not learned).
`DenseTrafficEnv.command(action)` gives the physical `EgoCommand`.

Reward per step (weights in ``config["reward"]``, `simharness.envs.reward`): a collision-free step on the
road earns ``alive + progress * min(speed made good / target_speed, 1)`` (target_speed 7 m/s, about the
traffic's median speed) less the comfort terms on what the ego did (measured acceleration, jerk, speed
across the traffic flow), each saturating at the scorecard's comfort bounds, less a term growing as the
ego's time-to-collision falls below 3 s; a new contact, judged as the
scorecard judges it, pays ``collision_at_fault`` (or ``collision_hit``) times the best episode's return.
So any collision-free episode outscores any episode with an at-fault collision. An episode terminates on
a collision (if ``terminate_on_collision``) or when the ego leaves the end of the road, and is truncated
after ``duration`` s; ``step`` after either raises RuntimeError until ``reset``.

Rendering (``render_mode="rgb_array"``): (300, 720, 3) uint8 top-down frames around the ego in the
project's drawing style, the same for both envs (`simharness.envs.render`); ``"human"`` shows them in a
window and is refused (`UserError`) without a display.

``info`` holds fixed-shape scalars only (vector envs stack them): ``t``, ``speed``, ``progress_m``,
``collided``, ``collisions``, ``at_fault_collisions``, ``on_road``, ``min_ttc`` (s, capped at 10),
``min_gap`` (m, capped at 100).
"""

from __future__ import annotations

import gymnasium as gym

from simharness.envs.config import DEFAULT_CONFIG
from simharness.envs.dense import DenseTrafficEnv, HighwayDenseEnv, SumoDenseEnv
from simharness.envs.observation import FEATURES

__all__ = ["DEFAULT_CONFIG", "FEATURES", "DenseTrafficEnv", "HighwayDenseEnv", "SumoDenseEnv"]


def _register() -> None:
    for env_id, cls in (("simharness/SumoDense-v0", "SumoDenseEnv"), ("simharness/HighwayDense-v0", "HighwayDenseEnv")):
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=f"simharness.envs:{cls}")


_register()
