"""`PolicyPlanner`: a policy trained on a simharness gym env drives the ego in the closed loop.

The loop (`simharness.closedloop.simulate`) hands a planner the current frame; this planner keeps the
last H frames itself, builds exactly the env's observation (`simharness.envs.observation`, the forecast
observation included, from its own predictor as the env's) and maps the policy's action to an
`EgoCommand` as the env does (`simharness.envs.actions`). Until the ego has H frames of history it
returns None (the simulator's own model drives), as the env's reset does. On the ego's first new contact
it sets `ended` and the loop stops the episode there, as the env terminates it.

    planner = load_policy_planner("ppo")                    # the shipped policy
    planner = load_policy_planner("path/to/policy.zip")     # any stable-baselines3 policy
    scene, issued, road, timing = simulate(spec, seed, None, planner, LoopConfig())

`load_policy_planner` is what `simharness closedloop --planner ppo|PATH.zip` calls. It reads an SB3 zip
without unpickling anything in it: the model's classes and spaces are rebuilt from the zip's JSON (and the
env config from the JSON note beside the zip when there is one), the weights are read by
``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from simharness.envs.actions import action_to_command
from simharness.envs.config import DEFAULT_CONFIG, resolve_config
from simharness.envs.observation import FEATURES, History, agents_observation, forecast_observation
from simharness.envs.reward import ego_safety
from simharness.errors import UserError
from simharness.scene import Forecast, Scene
from simharness.sim.base import EgoCommand, Frame

SHIPPED = Path(__file__).resolve().parent / "policies" / "ppo_highway_dense.zip"


class Policy(Protocol):
    """What SB3 models offer: predict(observation, deterministic) -> (action, state)."""

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]: ...


class PolicyPlanner:
    """`Planner` over a policy trained on a `DenseTrafficEnv` with env config `config` (defaults if None)."""

    def __init__(self, policy: Policy, config: dict[str, Any] | None = None, deterministic: bool = True,
                 end_on_collision: bool = True) -> None:
        self.config = resolve_config(DEFAULT_CONFIG, config, "PolicyPlanner")
        self.policy = policy
        self.deterministic = deterministic
        self.end_on_collision = end_on_collision
        self._predictor = None
        if self.config["predictor"]:
            from simharness.predictors import load_predictor

            self._predictor = load_predictor(self.config["predictor"])
        self._history = History(int(self.config["history_frames"]))
        self.reset()

    def reset(self) -> None:
        self._history.clear()
        self._ego_frames = 0
        self._contact_prev = True  # an overlap at the ego's first frame is the simulator's placing, not new
        self.ended = False

    def plan(self, now: Scene, forecast: Forecast | None) -> EgoCommand | None:
        """The policy's command for the next frame (None while the ego's history is shorter than H, or once the
        episode has `ended` on a collision)."""
        c = self.config
        frame = Frame(t=float(now.times[-1]) if now.num_frames else 0.0, agent_id=np.asarray(now.agent_id),
                      agent_type=now.agent_type, xy=now.xy[:, -1], heading=now.heading[:, -1],
                      speed=now.speed[:, -1], length=now.length, width=now.width,
                      ego=now.ego if now.ego >= 0 and now.valid[now.ego, -1] else -1,
                      extra={k: v[:, -1] for k, v in now.extra.items()})
        self._history.append(frame)
        self._ego_frames = self._ego_frames + 1 if frame.ego >= 0 else 0
        if self._ego_frames and self.end_on_collision:
            contact = ego_safety(frame).contact
            self.ended = self.ended or (contact and not self._contact_prev and self._ego_frames > 1)
            self._contact_prev = contact
        if self.ended or self._ego_frames < int(c["history_frames"]):
            return None
        k, h, rng = int(c["num_agents"]), int(c["history_frames"]), float(c["obs_range"])
        obs, near = agents_observation(self._history, k, h, rng)
        if c["flatten"]:
            obs = obs.reshape(-1)
        if self._predictor is not None:
            fc = forecast_observation(self._history, near, self._predictor, k, int(c["forecast_frames"]), rng,
                                      float(now.dt))
            obs = {"agents": obs, "forecast": fc.reshape(-1) if c["flatten"] else fc}
        action, _ = self.policy.predict(obs, deterministic=self.deterministic)
        return action_to_command(action, c, "PolicyPlanner", frame)


# ---------------------------------------------------------------------- loading SB3 zips without unpickling
def _space(desc: dict[str, Any], where: str) -> Any:
    """A gymnasium space from the readable fields SB3 writes beside its pickled one (Box, Discrete, Dict)."""
    from gymnasium import spaces

    kind = desc.get(":type:", "")
    if "Discrete" in kind:
        return spaces.Discrete(int(desc["n"]))
    if "Box" in kind:
        shape = _shape(desc)
        lo, hi = desc.get("low", "-1."), desc.get("high", "1.")
        if not (str(lo).lstrip("[ ").startswith("-1.") and str(hi).lstrip("[ ").startswith("1.")):
            raise UserError(f"{where}: a Box space that is not [-1, 1]: not a simharness env policy")
        return spaces.Box(-1.0, 1.0, shape, np.dtype(desc.get("dtype", "float32")))
    if "Dict" in kind:
        raise UserError(f"{where}: a Dict observation needs the JSON note beside the zip (bench/train_ppo.py "
                        "writes it) to rebuild its spaces")
    raise UserError(f"{where}: unsupported space {kind!r}; expected Box or Discrete")


def _shape(desc: dict[str, Any]) -> tuple[int, ...] | None:
    """The "_shape" SB3 writes for a space (a list, or its JSON text), or None."""
    shape = desc.get("_shape")
    if shape is None:
        return None
    return tuple(int(n) for n in (json.loads(shape) if isinstance(shape, str) else shape))


def _algorithm(policy_module: str) -> Any:
    """The SB3 algorithm class behind a policy class's module (actor-critic policies load as PPO)."""
    import stable_baselines3 as sb3

    for name in ("dqn", "sac", "td3", "ddpg"):
        if f".{name}." in policy_module:
            return getattr(sb3, name.upper())
    return sb3.PPO


def _policy_class(algorithm: Any, dict_obs: bool) -> Any:
    return algorithm.policy_aliases["MultiInputPolicy" if dict_obs else "MlpPolicy"]


def load_policy(path: Path, config: dict[str, Any]) -> Any:
    """The SB3 model in `path`, its pickled fields replaced by objects rebuilt from readable data (the zip's
    JSON and the env `config`), so loading it runs no code from the file."""
    from gymnasium import spaces
    from stable_baselines3.common.utils import ConstantSchedule

    from simharness.envs.actions import action_space
    from simharness.envs.dense import observation_space

    where = f"policy {path}"
    try:
        with zipfile.ZipFile(path) as z:
            data = json.loads(z.read("data"))
    except (zipfile.BadZipFile, KeyError, ValueError) as e:
        raise UserError(f"{where}: not a stable-baselines3 model ({type(e).__name__}: {e})") from None
    module = str(data.get("policy_class", {}).get("__module__", ""))
    if "stable_baselines3" not in module:
        raise UserError(f"{where}: not a stable-baselines3 model (policy class from {module or 'nowhere'})")
    algorithm = _algorithm(module)
    obs_space, act_space = observation_space(config), action_space(config)
    for key, space in (("observation_space", obs_space), ("action_space", act_space)):
        got = data.get(key, {})
        if "Dict" not in got.get(":type:", "") and not isinstance(space, type(_space(got, where))):
            raise UserError(f"{where}: its {key} is {got.get(':type:')}, the env config gives {space}")
        if _shape(got) is not None and _shape(got) != space.shape:
            raise UserError(f"{where}: its {key} has shape {_shape(got)}, the env config gives {space.shape}")
        if "Discrete" in got.get(":type:", "") and int(got.get("n", -1)) != space.n:
            raise UserError(f"{where}: its {key} has {got.get('n')} actions, the env config gives {space}")
    custom = {key: None for key, value in data.items() if isinstance(value, dict) and ":serialized:" in value}
    custom.update({"observation_space": obs_space, "action_space": act_space,
                   "policy_class": _policy_class(algorithm, isinstance(obs_space, spaces.Dict)),
                   "lr_schedule": ConstantSchedule(0.0), "learning_rate": 0.0})
    for key in ("clip_range", "exploration_schedule"):
        if key in custom:
            custom[key] = ConstantSchedule(0.0)
    try:
        return algorithm.load(path, device="cpu", custom_objects=custom)
    except Exception as e:  # a zip whose weights do not fit the rebuilt policy
        raise UserError(f"{where}: not a loadable stable-baselines3 model ({type(e).__name__}: {e})") from None


def policy_config(path: Path) -> dict[str, Any]:
    """The env config a policy was trained with: the JSON note beside it (bench/train_ppo.py's "env_config"),
    else read from the zip's spaces (a Discrete action space -> meta-actions, a 3-D Box -> unflattened)."""
    note = path.with_suffix(".json")
    if note.is_file():
        try:
            given = json.loads(note.read_text()).get("env_config", {})
        except ValueError as e:
            raise UserError(f"policy note {note}: not JSON ({e})") from None
        return {k: v for k, v in given.items() if k in DEFAULT_CONFIG and k not in ("scenario", "overrides")}
    try:
        with zipfile.ZipFile(path) as z:
            data = json.loads(z.read("data"))
    except (zipfile.BadZipFile, KeyError, ValueError) as e:
        raise UserError(f"policy {path}: not a stable-baselines3 model ({type(e).__name__}: {e})") from None
    config: dict[str, Any] = {}
    if "Discrete" in data.get("action_space", {}).get(":type:", ""):
        config["action"] = "discrete"
        config["lateral"] = int(data["action_space"].get("n", 12)) != 4  # Discrete(4): the longitudinal choices only
    shape = _shape(data.get("observation_space", {}))
    if shape and len(shape) == 3:
        config["flatten"] = False
        config["num_agents"], config["history_frames"] = shape[0] - 1, shape[1]
    elif shape:
        config["num_agents"] = shape[0] // (DEFAULT_CONFIG["history_frames"] * FEATURES) - 1
    return config


def load_policy_planner(path: str | Path = SHIPPED, config: dict[str, Any] | None = None) -> PolicyPlanner:
    """A `PolicyPlanner` over a stable-baselines3 zip: "ppo" (or no path) is the shipped HighwayDense-v0 policy.
    config: the env config it was trained with (None: from the JSON note beside it, else from its spaces)."""
    path = SHIPPED if str(path) == "ppo" else Path(path)
    if not path.is_file():
        raise UserError(f"policy {path}: no such file; expected a stable-baselines3 policy .zip (or 'ppo')")
    if config is None:
        config = policy_config(path)
    resolved = resolve_config(DEFAULT_CONFIG, config, f"policy {path}")
    return PolicyPlanner(load_policy(path, resolved), config)
