"""highway-env backend: `HighwaySimulator` (the `Simulator` protocol) over `HeteroHighwayEnv`.

The scenario file maps onto the env's config dict (`config_from_spec`); the
simulator resets the env with `spec.seed + seed`, then emits one `Frame` per
recorded instant (1 / record_hz s, `spec.steps_per_frame` dynamics steps).
It holds no gymnasium spaces: the gymnasium envs of `simharness.envs` wrap it.

Frames carry `extra["lateral_offset"]`: metres from the carriageway centre
line, + left of the direction of travel (here equal to y).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.scenario import ScenarioSpec
from simharness.sim.base import EgoCommand, Event, Frame, RoadGeometry
from simharness.sim.highway.world import HeteroHighwayEnv

__all__ = ["HeteroHighwayEnv", "HighwaySimulator", "config_from_spec", "road_geometry"]


def config_from_spec(spec: ScenarioSpec) -> dict[str, Any]:
    """`HeteroHighwayEnv` config for a scenario (demand_scale applied); UserError for what it cannot build."""
    where = spec.path or spec.name
    if spec.road.layout != "arterial":
        raise UserError(f"{where}: key 'road.layout': the highway backend builds 'arterial' roads only, "
                        f"got {spec.road.layout!r}")
    if spec.road.bidirectional:
        raise UserError(f"{where}: key 'road.bidirectional': the highway backend builds one direction only; "
                        "expected false")
    ego = None
    if spec.ego.enabled:
        ego = {"type": spec.ego.type, "insert_at": spec.ego.insert_at, "speed": spec.ego.speed,
               "reaction": spec.ego.reaction}
    return {
        "simulation_frequency": 1.0 / spec.step_length,
        "policy_frequency": spec.record_hz,
        "road_length": spec.road.length,
        "road_width": spec.road.width,
        "lanes": spec.road.lanes,
        "sidewalk_width": spec.road.sidewalk_width,
        "speed_limit": spec.road.speed_limit,
        "demand": {t.label: q for t, q in spec.flows().items()},
        "crossing_rate": spec.pedestrians.crossing_rate * spec.demand_scale,
        "walking_rate": spec.pedestrians.walking_rate * spec.demand_scale,
        "walking_speed": spec.pedestrians.speed,
        "behaviour_spread": spec.behaviour.spread,
        "speed_dev": spec.behaviour.speed_dev,
        "lateral_resolution": spec.sublane.lateral_resolution,
        "min_gap_lat": spec.sublane.min_gap_lat,
        "lane_discipline": spec.sublane.lane_discipline,
        "warmup": spec.warmup,
        "duration": spec.duration,
        "ego": ego,
        "events": [dataclasses.asdict(e) for e in spec.events],
    }


def road_geometry(length: float, width: float, lanes: int, sidewalk: float) -> RoadGeometry:
    """Carriageway [0, length] x [-width/2, width/2], sidewalks beside it, edge lines and lane lines."""
    def rect(y0: float, y1: float) -> np.ndarray:
        return np.array([[0.0, y0], [length, y0], [length, y1], [0.0, y1]])

    h = width / 2
    sidewalks = (rect(h, h + sidewalk), rect(-h - sidewalk, -h)) if sidewalk > 0 else ()
    ys = -h + width * np.arange(lanes + 1) / lanes
    markings = tuple(np.array([[0.0, y], [length, y]]) for y in ys)
    return RoadGeometry(drivable=(rect(-h, h),), sidewalks=sidewalks, markings=markings)


class HighwaySimulator:
    """One highway-env simulation of a scenario (`backend = "highway"`); follows `sim.base.Simulator`."""

    def __init__(self, spec: ScenarioSpec) -> None:
        self.spec = spec
        self.config = config_from_spec(spec)
        self.dt = spec.dt
        self.road = road_geometry(spec.road.length, spec.road.width, spec.road.lanes, spec.road.sidewalk_width)
        self.env = HeteroHighwayEnv(self.config, render_mode="rgb_array")
        self.frame_index = 0

    @property
    def traffic(self):  # noqa: ANN201 - the env's Traffic, for inspection
        return self.env.traffic

    def reset(self, seed: int) -> Frame:
        """Fill the road, run the warm-up unrecorded, return frame t = 0. Seeded by spec.seed + seed."""
        self.env.reset(seed=self.spec.seed + int(seed))
        self.frame_index = 0
        return self._frame(())

    def step(self, ego_command: EgoCommand | None = None) -> Frame:
        """Advance one recorded frame; ego_command (held for the frame) drives the ego, None: background model."""
        command = None if ego_command is None else (float(ego_command.acceleration),
                                                    float(ego_command.lateral_velocity))
        raw = self.env.advance(self.spec.steps_per_frame, command)
        self.frame_index += 1
        events = tuple(Event(kind="collision", t=t, agent_id="ego", other_id=a) if k == "collision_with" else
                       Event(kind=k, t=t, agent_id=a) for k, a, t in raw if k != "collision")
        return self._frame(events)

    def restart_ego(self) -> Frame:
        """A new ego run in the running traffic: the ego leaves and enters again as at reset; frame t = 0."""
        self.env.restart_ego()
        self.frame_index = 0
        return self._frame(())

    def _frame(self, events: tuple[Event, ...]) -> Frame:
        s = self.env.traffic.state
        ego = np.flatnonzero(s.is_ego)
        return Frame(
            t=round(self.frame_index * self.dt, 9), agent_id=s.agent_id.astype(str), agent_type=s.agent_type.copy(),
            xy=np.stack([s.x, s.y], -1).astype(np.float32), heading=s.headings().astype(np.float32),
            speed=np.hypot(s.vx, s.vy).astype(np.float32), length=s.length.astype(np.float32),
            width=s.width.astype(np.float32), ego=int(ego[0]) if ego.size else -1,
            extra={"lateral_offset": s.y.astype(np.float32)}, events=events,
        )

    def branch(self) -> HighwaySimulator:
        """An independent copy of the running simulation (env, traffic and RNGs deep-copied): stepped with
        the same ego commands it gives the same frames as the original would."""
        import copy

        return copy.deepcopy(self)

    def render(self) -> np.ndarray:
        """(H, W, 3) uint8 top-down view (highway-env's pygame renderer), headless; +y (left) up."""
        return self.env.render()

    def meta(self) -> dict[str, Any]:
        """What a Scene's meta should record about this run (backend, versions, counters)."""
        import highway_env

        t = self.env.traffic
        return {"backend": "highway", "highway_env": highway_env.__version__ if hasattr(highway_env, "__version__")
                else "", "dropped_arrivals": t.dropped, "queued_arrivals": len(t.queue),
                "emergency_stops": t.emergency_stops}

    def close(self) -> None:
        self.env.close()
