"""Agent classes of the highway backend: one highway-env `Vehicle` subclass per `AgentType`.

Each class carries its type's real footprint (`scene.DEFAULT_FOOTPRINT`) and
its driving parameters as class attributes, the way highway-env vehicles do
(`LENGTH`, `WIDTH`, `MAX_SPEED`, IDM's `ACC_MAX`, ...). The traffic itself is
simulated on arrays (`traffic.Traffic`); an agent object is a live
view of one row, so `vehicle.position` always reads the current state.
The values come from one table (`params`), which the vectorised dynamics read as arrays.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np
from highway_env.vehicle.kinematics import Vehicle

from simharness.scene import DEFAULT_FOOTPRINT, AgentType
from simharness.sim.highway.params import type_params

if TYPE_CHECKING:
    from simharness.sim.highway.traffic import Traffic


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

    def __init_subclass__(cls, **kwargs: object) -> None:
        """Each type's class attributes are its row of the parameter table (`params`)."""
        super().__init_subclass__(**kwargs)
        p = type_params(cls.AGENT_TYPE)
        cls.LENGTH, cls.WIDTH, cls.MAX_SPEED, cls.SPEED_FACTOR = p["length"], p["width"], p["v_max"], p["speed_factor"]
        cls.ACC_MAX, cls.COMFORT_ACC_MIN, cls.TIME_WANTED = p["a_max"], -p["b_comf"], p["headway"]
        cls.DISTANCE_WANTED, cls.LATERAL_SPEED_MAX = p["s0"], p["vy_max"]

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


class Bus(HeteroAgent):
    AGENT_TYPE = AgentType.BUS


class Truck(HeteroAgent):
    AGENT_TYPE = AgentType.TRUCK


class Rickshaw(HeteroAgent):
    AGENT_TYPE = AgentType.RICKSHAW


class Motorcycle(HeteroAgent):
    AGENT_TYPE = AgentType.MOTORCYCLE


class Scooter(HeteroAgent):
    AGENT_TYPE = AgentType.SCOOTER


class Bicycle(HeteroAgent):
    AGENT_TYPE = AgentType.BICYCLE


class Pedestrian(HeteroAgent):
    """Walks along the road edge (IDM at walking pace) or crosses it (gap acceptance)."""

    AGENT_TYPE = AgentType.PEDESTRIAN


class Other(HeteroAgent):
    AGENT_TYPE = AgentType.OTHER


AGENT_CLASSES: dict[AgentType, type[HeteroAgent]] = {
    c.AGENT_TYPE: c for c in (Car, Bus, Truck, Rickshaw, Motorcycle, Scooter, Bicycle, Pedestrian, Other)
}


def hex_rgb(color: str) -> tuple[int, int, int]:
    """"#rrggbb" -> (r, g, b) 0..255, as pygame wants."""
    c = color.lstrip("#")
    return int(c[0:2], 16), int(c[2:4], 16), int(c[4:6], 16)
