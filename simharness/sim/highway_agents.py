"""Agent classes of the highway backend: one highway-env `Vehicle` subclass per `AgentType`.

Each class carries its type's real footprint (`scene.DEFAULT_FOOTPRINT`) and
its driving parameters as class attributes, the way highway-env vehicles do
(`LENGTH`, `WIDTH`, `MAX_SPEED`, IDM's `ACC_MAX`, ...). The traffic itself is
simulated on arrays (`highway_traffic.Traffic`); an agent object is a live
view of one row, so `vehicle.position` always reads the current state.
`PARAMS` is the same table as arrays indexed by type code, for the vectorised
dynamics.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np
from highway_env.vehicle.kinematics import Vehicle

from simharness.scene import DEFAULT_FOOTPRINT, AgentType

if TYPE_CHECKING:
    from simharness.sim.highway_traffic import Traffic


class HeteroAgent(Vehicle):
    """A road agent of one `AgentType`, backed by a row of the traffic arrays.

    Class attributes (SI units):
      LENGTH, WIDTH        footprint (m)
      MAX_SPEED            absolute speed cap (m/s)
      SPEED_FACTOR         desired speed as a share of the road speed limit
      ACC_MAX              IDM maximum acceleration (m/s^2)
      COMFORT_ACC_MIN      IDM comfortable deceleration, negative (m/s^2)
      TIME_WANTED          IDM time headway (s)
      DISTANCE_WANTED      IDM standstill bumper-to-bumper gap (m)
      LATERAL_SPEED_MAX    fastest sideways drift at cruising speed (m/s)
    """

    AGENT_TYPE: ClassVar[AgentType] = AgentType.OTHER
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.OTHER]
    MAX_SPEED = 40.0
    SPEED_FACTOR = 1.0
    ACC_MAX = 2.0
    COMFORT_ACC_MIN = -3.0
    TIME_WANTED = 1.2
    DISTANCE_WANTED = 1.5
    LATERAL_SPEED_MAX = 1.0

    def __init__(self, traffic: Traffic, uid: int) -> None:
        self.traffic, self.uid = traffic, uid  # before Vehicle.__init__, whose setters need the row
        row = self._row
        s = traffic.state
        super().__init__(traffic.road, (s.x[row], s.y[row]), 0.0, float(s.vx[row]))
        self.color = hex_rgb(traffic.color_of(self.AGENT_TYPE, bool(s.is_ego[row])))

    def __repr__(self) -> str:
        where = f"at {self.position.round(1).tolist()}" if self.alive else "gone"
        return f"{type(self).__name__} #{self.uid} {where}"

    @property
    def _row(self) -> int:
        return self.traffic.row_of(self.uid)

    @property
    def alive(self) -> bool:
        return self.traffic.row_of(self.uid, missing=-1) >= 0

    @property
    def agent_id(self) -> str:
        return str(self.traffic.state.agent_id[self._row])

    # Live views of the arrays: reads are current, writes go to the simulation.
    @property
    def position(self) -> np.ndarray:
        s, r = self.traffic.state, self._row
        return np.array([s.x[r], s.y[r]])

    @position.setter
    def position(self, value: np.ndarray) -> None:
        s, r = self.traffic.state, self._row
        s.x[r], s.y[r] = float(value[0]), float(value[1])

    @property
    def speed(self) -> float:
        s, r = self.traffic.state, self._row
        return float(np.hypot(s.vx[r], s.vy[r]))

    @speed.setter
    def speed(self, value: float) -> None:
        self.traffic.state.vx[self._row] = float(value)

    @property
    def heading(self) -> float:
        return float(self.traffic.headings()[self._row])

    @heading.setter
    def heading(self, value: float) -> None:
        pass  # heading is the direction of motion, derived from the velocity

    def act(self, action: dict | str | None = None) -> None:
        pass  # driven by the vectorised road (`HeteroRoad.act`), not per object

    def step(self, dt: float) -> None:
        pass


class Car(HeteroAgent):
    AGENT_TYPE = AgentType.CAR
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.CAR]
    MAX_SPEED, SPEED_FACTOR = 40.0, 1.0
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 2.0, -3.0, 1.2, 1.5
    LATERAL_SPEED_MAX = 1.0


class Bus(HeteroAgent):
    AGENT_TYPE = AgentType.BUS
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.BUS]
    MAX_SPEED, SPEED_FACTOR = 25.0, 0.85
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 1.0, -2.0, 1.5, 2.0
    LATERAL_SPEED_MAX = 0.5


class Truck(HeteroAgent):
    AGENT_TYPE = AgentType.TRUCK
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.TRUCK]
    MAX_SPEED, SPEED_FACTOR = 25.0, 0.85
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 0.8, -2.0, 1.6, 2.0
    LATERAL_SPEED_MAX = 0.5


class Rickshaw(HeteroAgent):
    AGENT_TYPE = AgentType.RICKSHAW
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.RICKSHAW]
    MAX_SPEED, SPEED_FACTOR = 14.0, 0.8
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 1.4, -2.5, 1.0, 1.0
    LATERAL_SPEED_MAX = 0.8


class Motorcycle(HeteroAgent):
    AGENT_TYPE = AgentType.MOTORCYCLE
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.MOTORCYCLE]
    MAX_SPEED, SPEED_FACTOR = 30.0, 1.05
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 2.5, -3.5, 0.8, 0.8
    LATERAL_SPEED_MAX = 1.4


class Scooter(HeteroAgent):
    AGENT_TYPE = AgentType.SCOOTER
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.SCOOTER]
    MAX_SPEED, SPEED_FACTOR = 18.0, 0.9
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 2.0, -3.0, 0.8, 0.8
    LATERAL_SPEED_MAX = 1.2


class Bicycle(HeteroAgent):
    AGENT_TYPE = AgentType.BICYCLE
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.BICYCLE]
    MAX_SPEED, SPEED_FACTOR = 6.0, 0.4
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 1.0, -2.0, 1.0, 0.6
    LATERAL_SPEED_MAX = 0.6


class Pedestrian(HeteroAgent):
    """Walks along the road edge (IDM at walking pace) or crosses it (gap acceptance)."""

    AGENT_TYPE = AgentType.PEDESTRIAN
    LENGTH, WIDTH = DEFAULT_FOOTPRINT[AgentType.PEDESTRIAN]
    MAX_SPEED, SPEED_FACTOR = 3.0, 0.0  # desired speed comes from the scenario's walking speed
    ACC_MAX, COMFORT_ACC_MIN, TIME_WANTED, DISTANCE_WANTED = 1.0, -2.0, 0.5, 0.4
    LATERAL_SPEED_MAX = 0.0


class Other(HeteroAgent):
    AGENT_TYPE = AgentType.OTHER


AGENT_CLASSES: dict[AgentType, type[HeteroAgent]] = {
    c.AGENT_TYPE: c for c in (Car, Bus, Truck, Rickshaw, Motorcycle, Scooter, Bicycle, Pedestrian, Other)
}


def _param_table() -> dict[str, np.ndarray]:
    """Class attributes as (9,) float64 arrays indexed by `AgentType` code."""
    attrs = {"length": "LENGTH", "width": "WIDTH", "v_max": "MAX_SPEED", "speed_factor": "SPEED_FACTOR",
             "a_max": "ACC_MAX", "b_comf": "COMFORT_ACC_MIN", "headway": "TIME_WANTED", "s0": "DISTANCE_WANTED",
             "vy_max": "LATERAL_SPEED_MAX"}
    table = {k: np.array([getattr(AGENT_CLASSES[t], a) for t in AgentType], np.float64) for k, a in attrs.items()}
    table["b_comf"] = -table["b_comf"]  # stored positive for the IDM formula
    return table


PARAMS: dict[str, np.ndarray] = _param_table()


def hex_rgb(color: str) -> tuple[int, int, int]:
    """"#rrggbb" -> (r, g, b) 0..255, as pygame wants."""
    c = color.lstrip("#")
    return int(c[0:2], 16), int(c[2:4], 16), int(c[4:6], 16)
