"""`PolicyPlanner`: a policy trained on a simharness gym env drives the ego in the closed loop.

The loop (`simharness.closedloop.simulate`) hands a planner the current frame; this planner keeps the
last H frames itself, builds exactly the env's observation (`simharness.envs.observation`) and maps
the policy's normalised action to an `EgoCommand` as the env does. Until the ego has H frames of
history it returns None (the simulator's own model drives), as the env's reset does. The forecast the
loop passes is not used: policies trained with the env's "forecast" observation are not supported here.

    planner = load_policy_planner("simharness/policies/ppo_highway_dense.zip")   # SB3 PPO zip
    scene, issued, road, timing = simulate(spec, seed, None, planner, LoopConfig())
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import numpy as np

from simharness.envs.config import DEFAULT_CONFIG, resolve_config
from simharness.envs.dense import action_to_command
from simharness.envs.observation import History, agents_observation
from simharness.errors import UserError
from simharness.scene import Forecast, Scene
from simharness.sim.base import EgoCommand, Frame

SHIPPED = Path(__file__).resolve().parent / "policies" / "ppo_highway_dense.zip"


class Policy(Protocol):
    """What SB3 models offer: predict(observation, deterministic) -> (action, state)."""

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]: ...


class PolicyPlanner:
    """`Planner` over a policy trained on a `DenseTrafficEnv` with env config `config` (defaults if None)."""

    def __init__(self, policy: Policy, config: dict[str, Any] | None = None, deterministic: bool = True) -> None:
        self.config = resolve_config(DEFAULT_CONFIG, config, "PolicyPlanner")
        if self.config["predictor"]:
            raise UserError("PolicyPlanner config: key 'predictor': policies with the forecast observation are "
                            "not supported in the closed loop; expected None")
        self.policy = policy
        self.deterministic = deterministic
        self._history = History(int(self.config["history_frames"]))
        self._ego_frames = 0

    def reset(self) -> None:
        self._history.clear()
        self._ego_frames = 0

    def plan(self, now: Scene, forecast: Forecast | None) -> EgoCommand | None:
        """The policy's command for the next frame (None while the ego's history is shorter than H)."""
        c = self.config
        frame = Frame(t=float(now.times[-1]) if now.num_frames else 0.0, agent_id=np.asarray(now.agent_id),
                      agent_type=now.agent_type, xy=now.xy[:, -1], heading=now.heading[:, -1],
                      speed=now.speed[:, -1], length=now.length, width=now.width,
                      ego=now.ego if now.ego >= 0 and now.valid[now.ego, -1] else -1)
        self._history.append(frame)
        self._ego_frames = self._ego_frames + 1 if frame.ego >= 0 else 0
        if self._ego_frames < int(c["history_frames"]):
            return None
        obs, _ = agents_observation(self._history, int(c["num_agents"]), int(c["history_frames"]),
                                    float(c["obs_range"]))
        action, _ = self.policy.predict(obs, deterministic=self.deterministic)
        return action_to_command(action, c, "PolicyPlanner")


def load_policy_planner(path: str | Path = SHIPPED, config: dict[str, Any] | None = None) -> PolicyPlanner:
    """A `PolicyPlanner` over a stable-baselines3 PPO zip (the shipped HighwayDense-v0 policy by default)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"policy {path}: no such file; expected a stable-baselines3 PPO .zip")
    from stable_baselines3 import PPO

    try:
        model = PPO.load(path, device="cpu")
    except Exception as e:  # a zip that is not an SB3 model
        raise UserError(f"policy {path}: not a stable-baselines3 PPO model ({type(e).__name__}: {e})") from None
    return PolicyPlanner(model, config)
