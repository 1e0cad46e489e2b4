"""Env configuration: documented defaults (like highway-env's ``default_config()``) and their checks.

``gymnasium.make(id, config={...})`` merges the given keys into `DEFAULT_CONFIG` ("reward" is merged
key by key); unknown keys, non-finite numbers and out-of-range values are refused with one line
(`UserError`) before anything is built.
"""

from __future__ import annotations

import copy
import math
from typing import Any

from simharness.errors import UserError

DEFAULT_CONFIG: dict[str, Any] = {
    "scenario": None,  # scenario file or shipped name; each env id sets its own default
    "overrides": {},  # dotted scenario keys, e.g. {"demand_scale": 0.5}
    "reaction": None,  # reactive | cut_in | ignore; None keeps the scenario's
    "duration": 20.0,  # seconds of driving per episode (then truncated)
    "warmup": None,  # override the scenario's warm-up (s); None keeps it
    "episodes_per_warmup": 20,  # reset() without a seed re-inserts the ego into the running traffic this
    # many times before warming up afresh (1: every reset warms up; reset(seed=...) always does)
    "num_agents": 16,  # K nearest agents observed
    "history_frames": 5,  # H frames of history per agent
    "obs_range": 60.0,  # m: positions are divided by this; agents farther away are not observed
    "predictor": None,  # e.g. "const-vel", "traphic" or "mine.py:Model" (docs/predictors.md): adds the "forecast"
    # observation
    "forecast_frames": 10,  # Ff forecast frames in the observation
    "max_accel": 2.5,  # m/s^2 for action[0] = +1
    "max_decel": 7.0,  # m/s^2 of braking for action[0] = -1
    "max_lateral_speed": 1.5,  # m/s for action[1] = +-1
    "action": "continuous",  # continuous: Box(-1, 1, (2,)); discrete: Discrete(12) meta-actions (DISCRETE_ACTIONS);
    # speed: Discrete(12) target-speed meta-actions (SPEED_ACTIONS); follow: the same, keeping IDM's gap to the
    # agent ahead
    "lateral": True,  # meta-actions only: False drops the nudges (Discrete(4), the line held), as highway-env's
    # DiscreteMetaAction(lateral=False)
    "flatten": True,  # observation as a 1-D vector (reshape to (K + 1, H, F)); False: the (K + 1, H, F) array
    "terminate_on_collision": True,
    "target_speed": 7.0,  # m/s at which the progress term is full: about the dense traffic's median speed (both
    # default scenarios), so driving with the flow earns the full term and creeping little; None: the road's limit
    # Reward weights (`simharness.envs.reward`): per collision-free step on the road, alive + progress *
    # min(speed made good / target_speed, 1), plus the comfort terms, each weight * min((measured / bound)^2, 1),
    # plus ttc * max(1 - time-to-collision / 3 s, 0); a collision step pays its weight times
    # steps * (alive + progress + |accel| + |jerk| + |lateral| + |ttc|).
    "reward": {"alive": 0.1, "progress": 0.9, "accel": -0.05, "jerk": -0.05, "lateral": -0.05, "ttc": -0.3,
               "collision_at_fault": -1.0, "collision_hit": -0.5},
}
REACTIONS = (None, "reactive", "cut_in", "ignore")
ACTIONS = ("continuous", "discrete", "speed", "follow")
_POSITIVE = ("duration", "obs_range", "max_accel", "max_decel", "max_lateral_speed")
_COUNTS = ("num_agents", "history_frames", "forecast_frames", "episodes_per_warmup")


def resolve_config(defaults: dict[str, Any], given: dict[str, Any] | None, where: str) -> dict[str, Any]:
    """`defaults` updated with `given` (reward merged per term), checked; UserError names the key."""
    config = copy.deepcopy(defaults)
    if given is not None and not isinstance(given, dict):
        raise UserError(f"{where} config: expected a dict, got {type(given).__name__}")
    for key, value in (given or {}).items():
        if key not in config:
            raise UserError(f"{where} config: unknown key {key!r}; expected one of {', '.join(sorted(config))}")
        if key == "reward":
            if not isinstance(value, dict):
                raise UserError(f"{where} config: key 'reward': expected a dict of term -> weight")
            bad = sorted(set(value) - set(config["reward"]))
            if bad:
                raise UserError(f"{where} config: unknown reward term {bad[0]!r}; expected one of "
                                f"{', '.join(sorted(config['reward']))}")
            value = {**config["reward"], **value}
        config[key] = value
    _check(config, where)
    return config


def _number(where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(f"{where} config: key {key!r}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise UserError(f"{where} config: key {key!r}: expected a finite number, got {value!r}")
    return float(value)


def _check(c: dict[str, Any], where: str) -> None:
    for key in _POSITIVE:
        if _number(where, key, c[key]) <= 0:
            raise UserError(f"{where} config: key {key!r}: expected > 0, got {c[key]!r}")
    for key in _COUNTS:
        if isinstance(c[key], bool) or not isinstance(c[key], int) or c[key] < 1:
            raise UserError(f"{where} config: key {key!r}: expected an integer >= 1, got {c[key]!r}")
    if c["warmup"] is not None and _number(where, "warmup", c["warmup"]) < 0:
        raise UserError(f"{where} config: key 'warmup': expected >= 0 or None, got {c['warmup']!r}")
    for term, weight in c["reward"].items():
        _number(where, f"reward.{term}", weight)
    if c["target_speed"] is not None and _number(where, "target_speed", c["target_speed"]) <= 0:
        raise UserError(f"{where} config: key 'target_speed': expected > 0 or None, got {c['target_speed']!r}")
    if c["action"] not in ACTIONS:
        raise UserError(f"{where} config: key 'action': expected one of {ACTIONS}, got {c['action']!r}")
    for key in ("flatten", "terminate_on_collision", "lateral"):
        if not isinstance(c[key], bool):
            raise UserError(f"{where} config: key {key!r}: expected true or false, got {c[key]!r}")
    if c["reaction"] not in REACTIONS:
        raise UserError(f"{where} config: key 'reaction': expected one of {REACTIONS}, got {c['reaction']!r}")
    if not isinstance(c["overrides"], dict):
        raise UserError(f"{where} config: key 'overrides': expected a dict of dotted scenario keys")
    for key, value in c["overrides"].items():
        if isinstance(value, float) and not math.isfinite(value):
            raise UserError(f"{where} config: key 'overrides.{key}': expected a finite number, got {value!r}")
