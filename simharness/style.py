"""The drawing style shared by the report figures and the simulators' own renderers: colours per agent type.

A leaf module (numpy and the Scene's types only), so that a backend can draw without importing the report.
"""

from __future__ import annotations

import numpy as np

from simharness.scene import AgentType

TYPE_COLORS: dict[AgentType, str] = {
    AgentType.CAR: "#1f77b4",
    AgentType.BUS: "#d62728",
    AgentType.TRUCK: "#8c564b",
    AgentType.RICKSHAW: "#2ca02c",
    AgentType.MOTORCYCLE: "#ff7f0e",
    AgentType.SCOOTER: "#e377c2",
    AgentType.BICYCLE: "#17becf",
    AgentType.PEDESTRIAN: "#9467bd",
    AgentType.OTHER: "#7f7f7f",
}
EGO_COLOR = "#000000"


def type_colors(agent_type: np.ndarray) -> list[str]:
    """(N,) int8 -> N colour strings."""
    return [TYPE_COLORS[AgentType(int(t))] for t in agent_type]
