"""The env's actions: a continuous Box or a discrete set of meta-actions, and their physical `EgoCommand`.

Continuous (``config["action"] = "continuous"``): ``Box(-1, 1, (2,))``; ``a[0]`` longitudinal
acceleration, ``a[0] * max_accel`` when positive and ``a[0] * max_decel`` when negative (m/s^2); ``a[1]``
lateral velocity, ``a[1] * max_lateral_speed`` (m/s, + left). Clipped to [-1, 1]; NaN or inf refused.

Discrete (``"discrete"``): ``Discrete(12)``, meta-actions for lane-less traffic, index = 3 * longitudinal +
lateral over the `LONGITUDINAL` and `LATERAL` sets below (in the continuous action's units), e.g. 10 is
"faster, straight", 7 "hold, straight" and 3 "slower, nudge left". Each is held for the next frame, like a
continuous action.

Speed (``"speed"``): ``Discrete(12)``, index = 3 * speed + lateral over the `TARGET_SPEEDS` (m/s) and the same
`LATERAL` set: the ego's acceleration closes the gap to the chosen speed in `SPEED_TAU` s, within
[-max_decel, max_accel], so "cruise" keeps cruising speed and "stop" brakes as hard as allowed; e.g. 7 is
"cruise, straight" and 1 "stop, straight". `SPEED_META_ACTIONS` names them.

With ``config["lateral"] = False`` each meta-action set keeps its longitudinal choices only, ``Discrete(4)``, index
= the longitudinal (or speed) choice, the line held (highway-env's ``DiscreteMetaAction(lateral=False)``).

Follow (``"follow"``): the same ``Discrete(12)`` target speeds and nudges, and the ego keeps its distance to the
agent ahead: the acceleration is the "speed" one capped by IDM's interaction term, a_max (1 - (s* / s)^2) with
s* = s0 + v T + v (v - v_lead) / (2 sqrt(a_max b)), s the gap to the nearest agent whose box reaches into the
ego's corridor (its width plus a margin on each side) at its current state, with the prediction-driven
planner's IDM constants (`PDMConfig`). The policy chooses where and how fast to drive; the car-following, as
in the hierarchical set-ups of the RL driving literature (high-level decisions over an IDM controller), is not
learned.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

from simharness.envs.observation import ego_rotation
from simharness.pdm_planner import PDMConfig
from simharness.sim.base import EgoCommand, Frame
from simharness.sim.highway.dynamics import half_extents

# name -> normalised a[0]: brake hard (-max_decel), ease off, hold speed, speed up
LONGITUDINAL = {"brake": -1.0, "slower": -0.3, "hold": 0.0, "faster": 0.6}
# name -> normalised a[1]: a nudge is half the lateral speed limit
LATERAL = {"nudge left": 0.5, "straight": 0.0, "nudge right": -0.5}
META_ACTIONS = [f"{lon}, {lat}" for lon in LONGITUDINAL for lat in LATERAL]  # index -> name
DISCRETE_ACTIONS = np.array([[a, b] for a in LONGITUDINAL.values() for b in LATERAL.values()])  # (12, 2)
# name -> target speed (m/s): around the dense traffic's median speed (about 7 m/s on both default scenarios)
TARGET_SPEEDS = {"stop": 0.0, "slow": 3.5, "cruise": 7.0, "fast": 10.5}
SPEED_TAU = 0.5  # s: the speed error is closed at (error / SPEED_TAU) m/s^2, clipped to the limits
SPEED_META_ACTIONS = [f"{lon}, {lat}" for lon in TARGET_SPEEDS for lat in LATERAL]  # index -> name
SPEED_ACTIONS = np.array([[v, b] for v in TARGET_SPEEDS.values() for b in LATERAL.values()])  # (12, 2) m/s, a[1]
META = ("discrete", "speed", "follow")  # the action kinds that are meta-action indices
STRAIGHT = list(LATERAL).index("straight")  # the lateral choice of a meta-action with the line held
_IDM = PDMConfig()  # the "follow" gap keeping: the planner's IDM constants and corridor margin


def leader(frame: Frame, margin: float = _IDM.corridor_margin) -> tuple[float, float]:
    """(gap m, speed m/s along the ego's heading) of the nearest agent ahead of the ego whose box reaches into its
    corridor (the ego's width plus `margin` on each side), all at their current state; (inf, 0) when none.
    The gap is between the boxes' extents along the ego's heading, at least 0.1 m."""
    e = frame.ego
    origin, rot, h = ego_rotation(frame)
    lon, lat = rot @ (frame.xy.astype(np.float64) - origin).T
    dh = frame.heading.astype(np.float64) - h
    half_lon, half_lat = half_extents(frame.length, frame.width, dh)  # the boxes on the ego's axes
    gap = lon - half_lon - 0.5 * float(frame.length[e])
    ahead = (lon > 0) & (np.abs(lat) < half_lat + 0.5 * float(frame.width[e]) + margin)
    ahead[e] = False
    if not ahead.any():
        return math.inf, 0.0
    i = int(np.argmin(np.where(ahead, gap, np.inf)))
    return max(float(gap[i]), 0.1), float(frame.speed[i] * np.cos(dh[i]))


def follow_acceleration(target: float, speed: float, gap: float, lead_speed: float, max_accel: float,
                        max_decel: float) -> float:
    """m/s^2: the "speed" meta-action's acceleration towards target (m/s) from speed, capped by IDM's
    interaction term for a leader gap (m) ahead moving at lead_speed (m/s); within [-max_decel, max_accel]."""
    acc = (target - speed) / SPEED_TAU
    if math.isfinite(gap):
        want = _IDM.idm_standstill + max(0.0, speed * _IDM.idm_headway_s
                                         + speed * (speed - lead_speed) / (2.0 * math.sqrt(max_accel * _IDM.idm_decel)))
        acc = min(acc, max_accel * (1.0 - (want / gap) ** 2))
    return min(max(acc, -max_decel), max_accel)


def meta_actions(config: dict[str, Any]) -> int:
    """How many meta-actions `config` gives: 12, or 4 (the longitudinal choices) without `lateral`."""
    return len(DISCRETE_ACTIONS) if config["lateral"] else len(DISCRETE_ACTIONS) // len(LATERAL)


def action_space(config: dict[str, Any]) -> spaces.Space:
    """The env's action space under `config["action"]` (and `config["lateral"]` for the meta-actions)."""
    if config["action"] in META:
        return spaces.Discrete(meta_actions(config))
    return spaces.Box(-1.0, 1.0, (2,), np.float32)


def action_to_command(action: Any, config: dict[str, Any], where: str = "env", frame: Frame | None = None
                      ) -> EgoCommand:
    """An action (module docstring) -> `EgoCommand` (m/s^2, m/s) under `config`'s limits; frame: the present one,
    which the "speed" meta-actions steer from (the ego's speed) and "follow" keeps its gap in (no frame, or no
    ego in it: standing, nobody ahead). ValueError for a non-finite continuous action or a meta-action index out
    of range."""
    a = np.asarray(action)
    if config["action"] in META:
        last = meta_actions(config) - 1
        if a.size != 1 or not (np.issubdtype(a.dtype, np.integer) or float(a.ravel()[0]).is_integer()):
            raise ValueError(f"{where}: action {action!r}: expected one meta-action index in 0..{last}")
        i = int(a.ravel()[0])
        if not 0 <= i <= last:
            raise ValueError(f"{where}: action {i}: expected a meta-action index in 0..{last}")
        if not config["lateral"]:  # index = the longitudinal choice, the line held
            i = len(LATERAL) * i + STRAIGHT
        if config["action"] != "discrete":
            target, lat = SPEED_ACTIONS[i].tolist()
            ego = frame is not None and frame.ego >= 0
            speed = float(frame.speed[frame.ego]) if ego else 0.0
            gap, lead = leader(frame) if ego and config["action"] == "follow" else (math.inf, 0.0)
            acc = follow_acceleration(target, speed, gap, lead, float(config["max_accel"]), float(config["max_decel"]))
            return EgoCommand(float(acc), float(lat * config["max_lateral_speed"]))
        acc, lat = DISCRETE_ACTIONS[i].tolist()
    else:
        a = a.astype(np.float64)
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


def command_to_action(command: EgoCommand, config: dict[str, Any]) -> np.ndarray:
    """The continuous Box action (2,) float32 in [-1, 1] that `action_to_command` maps to `command` under
    `config`'s limits (clipped where the command exceeds them): how an expert planner's command is labelled."""
    acc = float(command.acceleration)
    a0 = acc / config["max_accel"] if acc >= 0 else acc / config["max_decel"]
    a1 = float(command.lateral_velocity) / config["max_lateral_speed"]
    return np.clip(np.array([a0, a1], np.float32), -1.0, 1.0)
