"""The fixed "follow" policy: always "cruise, straight" over the env's IDM gap keeping, a reference for the
learned ones (how much of a "follow" policy's score is the car-following it is given, not what it learned).

    python bench/score_ppo.py --egos const-vel,cruise=examples/cruise_policy.py:Cruise,ppo=PATH.zip
    simharness closedloop highway_mixed_dense --planner examples/cruise_policy.py:Cruise --seeds 100-115
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simharness.envs.actions import SPEED_META_ACTIONS
from simharness.policy_planner import PolicyPlanner

CRUISE = SPEED_META_ACTIONS.index("cruise, straight")


class _Constant:
    """A policy that always answers `action`."""

    def __init__(self, action: int) -> None:
        self.action = np.int64(action)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:
        return self.action, state


class Cruise(PolicyPlanner):
    """`PolicyPlanner` of the constant "cruise, straight" policy under the "follow" actions."""

    def __init__(self) -> None:
        super().__init__(_Constant(CRUISE), {"action": "follow"})
