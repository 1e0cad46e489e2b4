"""Driving parameters of each agent type on the highway backend (SI units), as one table.

The agent classes (`agents`) carry them as highway-env style class attributes; `PARAMS` is the same
table as (9,) arrays indexed by `AgentType` code, for the vectorised dynamics (`traffic`, `events`).

Columns: length, width (m, the type's footprint); v_max (m/s, absolute speed cap); speed_factor
(desired speed as a share of the road speed limit); a_max (IDM maximum acceleration, m/s^2); b_comf
(IDM comfortable deceleration, positive, m/s^2); headway (IDM time headway, s); s0 (IDM standstill gap,
m); vy_max (fastest sideways drift at cruising speed, m/s).
"""

from __future__ import annotations

import numpy as np

from simharness.scene import DEFAULT_FOOTPRINT, AgentType

#                               v_max speed_factor a_max b_comf headway  s0  vy_max
_DRIVING: dict[AgentType, tuple[float, float, float, float, float, float, float]] = {
    AgentType.CAR: (40.0, 1.0, 2.0, 3.0, 1.2, 1.5, 1.0),
    AgentType.BUS: (25.0, 0.85, 1.0, 2.0, 1.5, 2.0, 0.5),
    AgentType.TRUCK: (25.0, 0.85, 0.8, 2.0, 1.6, 2.0, 0.5),
    AgentType.RICKSHAW: (14.0, 0.8, 1.4, 2.5, 1.0, 1.0, 0.8),
    AgentType.MOTORCYCLE: (30.0, 1.05, 2.5, 3.5, 0.8, 0.8, 1.4),
    AgentType.SCOOTER: (18.0, 0.9, 2.0, 3.0, 0.8, 0.8, 1.2),
    AgentType.BICYCLE: (6.0, 0.4, 1.0, 2.0, 1.0, 0.6, 0.6),
    AgentType.PEDESTRIAN: (3.0, 0.0, 1.0, 2.0, 0.5, 0.4, 0.0),  # desired speed: the scenario's walking speed
    AgentType.OTHER: (40.0, 1.0, 2.0, 3.0, 1.2, 1.5, 1.0),
}
_COLUMNS = ("v_max", "speed_factor", "a_max", "b_comf", "headway", "s0", "vy_max")


def type_params(agent_type: AgentType) -> dict[str, float]:
    """One type's row: length, width and the driving columns above."""
    length, width = DEFAULT_FOOTPRINT[agent_type]
    return {"length": float(length), "width": float(width), **dict(zip(_COLUMNS, _DRIVING[agent_type], strict=True))}


PARAMS: dict[str, np.ndarray] = {
    k: np.array([type_params(t)[k] for t in AgentType], np.float64) for k in ("length", "width", *_COLUMNS)}
