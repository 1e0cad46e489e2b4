"""`HeteroHighwayEnv`: a highway-env environment of dense, mixed, lane-free traffic.

Feels like highway-env: a config dict with documented defaults
(`HeteroHighwayEnv.default_config()`), `render_mode="rgb_array"`, `env.road`
with a `RoadNetwork` of straight lanes and `road.vehicles` of per-type
`Vehicle` subclasses (`agents`). What differs is underneath:
`road.act()`/`road.step()` move every agent at once on arrays
(`traffic.Traffic`), so the cost of a step stays low with hundreds of
agents, and vehicles are not tied to lanes.

Observation: (observation_count, 8) rows [present, x, y, vx, vy, length, width, type] of the agents
nearest the ego (or the road centre). Action: [acceleration m/s^2, lateral velocity m/s] for the ego,
when config["ego"] is set. Reward: the ego's speed over the speed limit, -1 on a collision.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.graphics import EnvViewer
from highway_env.envs.common.observation import ObservationType
from highway_env.road.lane import LineType, StraightLane
from highway_env.road.road import Road, RoadNetwork

from simharness.metrics.separating_axis import overlaps_with
from simharness.scene import AgentType
from simharness.sim.highway.agents import AGENT_CLASSES, HeteroAgent
from simharness.sim.highway.events import EventScript
from simharness.sim.highway.params import PARAMS
from simharness.sim.highway.traffic import B_EGO, Traffic
from simharness.style import EGO_COLOR, TYPE_COLORS


def agent_color(agent_type: AgentType, is_ego: bool) -> str:
    return EGO_COLOR if is_ego else TYPE_COLORS[agent_type]


class HeteroRoad(Road):
    """A highway-env `Road` whose agents live in a `Traffic`; `vehicles` are live views, built on access."""

    def __init__(self, network: RoadNetwork, traffic: Traffic) -> None:
        self.traffic = traffic
        self._objects: dict[int, HeteroAgent] = {}
        super().__init__(network=network, vehicles=None, road_objects=[], record_history=False)

    @property
    def vehicles(self) -> list[HeteroAgent]:
        """Agent objects in row order (created lazily: the simulation itself never needs them)."""
        s = self.traffic.state
        objs = {}
        for uid, t in zip(s.uid.tolist(), s.agent_type.tolist(), strict=True):  # on access only, not per step
            objs[uid] = self._objects.get(uid) or AGENT_CLASSES[AgentType(t)](self.traffic, uid)
        self._objects = objs
        return list(objs.values())

    @vehicles.setter
    def vehicles(self, value: list) -> None:
        if value:
            raise ValueError("agents enter through HeteroRoad.traffic (try_insert), not road.vehicles")

    def act(self) -> None:
        pass  # decisions are taken inside Traffic.step, all agents at once

    def step(self, dt: float) -> None:
        self.traffic.step(dt)


def make_network(length: float, width: float, lanes: int, sidewalk: float) -> RoadNetwork:
    """Straight lanes from x = 0 to length across y in [-width/2, width/2]; sidewalks as unmarked lanes."""
    net = RoadNetwork()
    w = width / lanes
    for k in range(lanes):
        y = -width / 2 + (k + 0.5) * w
        kinds = (LineType.CONTINUOUS_LINE if k == 0 else LineType.STRIPED,
                 LineType.CONTINUOUS_LINE if k == lanes - 1 else LineType.NONE)
        net.add_lane("a", "b", StraightLane([0, y], [length, y], width=w, line_types=kinds))
    if sidewalk > 0:
        for side in (-1, 1):
            y = side * (width + sidewalk) / 2
            kinds = (LineType.CONTINUOUS, LineType.NONE) if side < 0 else (LineType.NONE, LineType.CONTINUOUS)
            net.add_lane("s", "t" if side < 0 else "u", StraightLane([0, y], [length, y], width=sidewalk,
                                                                     line_types=kinds, forbidden=True))
    return net


class AgentArrayObservation(ObservationType):
    """(count, 8) [present, x, y, vx, vy, length, width, type] of the agents nearest the ego or road centre."""

    def __init__(self, env: HeteroHighwayEnv, count: int) -> None:
        super().__init__(env)
        self.count = count

    def space(self) -> spaces.Space:
        return spaces.Box(-np.inf, np.inf, (self.count, 8), np.float32)

    def observe(self) -> np.ndarray:
        out = np.zeros((self.count, 8), np.float32)
        s = self.env.traffic.state
        if s.n == 0:
            return out
        centre = self.env.view_centre()
        order = np.argsort(np.hypot(s.x - centre[0], s.y - centre[1]), kind="stable")[: self.count]
        out[: order.size] = np.stack([np.ones(order.size), s.x[order], s.y[order], s.vx[order], s.vy[order],
                                      s.length[order], s.width[order], s.agent_type[order]], -1)
        return out


class HeteroViewer(EnvViewer):
    """highway-env's viewer, centred on the ego (or the middle of the road) at config["view_length"] metres."""

    def __init__(self, env: HeteroHighwayEnv) -> None:
        super().__init__(env)
        self.sim_surface.scaling = env.config["screen_width"] / env.config["view_length"]
        self.sim_surface.centering_position = [0.5, 0.5]

    def window_position(self) -> np.ndarray:
        return self.env.view_centre()


class HeteroHighwayEnv(AbstractEnv):
    """Dense mixed traffic without lanes, with crossing and walking pedestrians (see module doc)."""

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        config = super().default_config()
        config.update({
            "simulation_frequency": 10,  # [Hz] dynamics steps per second
            "policy_frequency": 5,  # [Hz] env steps (ego decisions) per second
            "road_length": 500.0,  # [m] straight carriageway from x = 0
            "road_width": 10.5,  # [m] carriageway width, centred on y = 0 (+y left)
            "lanes": 1,  # marked lanes; 1 = one wide lane-less carriageway
            "sidewalk_width": 2.0,  # [m] each side
            "speed_limit": 13.9,  # [m/s]; desired speeds are a per-type share of it
            "demand": {"car": 1200.0, "motorcycle": 1500.0, "rickshaw": 500.0, "bus": 100.0},  # [veh/h] by type
            "crossing_rate": 0.0,  # [ped/h] pedestrians crossing the carriageway
            "walking_rate": 0.0,  # [ped/h] pedestrians walking along the edges, with the traffic
            "walking_speed": 1.3,  # [m/s] mean
            "behaviour_spread": 0.5,  # 0 all drivers alike .. 1 aggressive to conservative
            "speed_dev": 0.1,  # std of each driver's desired-speed factor
            "lateral_resolution": 0.35,  # [m] spacing of candidate lateral offsets
            "min_gap_lat": 0.3,  # [m] side-to-side gap agents keep
            "lane_discipline": 0.0,  # >= 0.5 with lanes > 1: vehicles keep to lane centres
            "decision_period": 0.5,  # [s] how often each vehicle re-chooses its lateral offset
            "warmup": 60.0,  # [s] run unobserved at reset after filling the road
            "duration": 60.0,  # [s] episode length (truncation)
            "events": [],  # scripted events: scenario.EventSpec fields as dicts (see events.py)
            "ego": None,  # {"type": "car", "insert_at": 0.0, "speed": 8.0, "reaction": "reactive"|"cut_in"|"ignore"}
            "observation_count": 32,  # agents in the observation
            "screen_width": 1200,  # [px]
            "screen_height": 240,  # [px]
            "view_length": 120.0,  # [m] of road across the screen
            "offscreen_rendering": True,
        })
        return config

    def __init__(self, config: dict | None = None, render_mode: str | None = "rgb_array") -> None:
        self._ready = False  # AbstractEnv.__init__ resets once: keep that road empty
        super().__init__(config, render_mode)
        self._ready = True

    # ------------------------------------------------------------------ gym plumbing
    def define_spaces(self) -> None:
        self.observation_type = AgentArrayObservation(self, int(self.config["observation_count"]))
        self.action_type = None
        self.observation_space = self.observation_type.space()
        self.action_space = spaces.Box(np.array([-B_EGO, -2.0], np.float32), np.array([4.0, 2.0], np.float32))

    @property
    def vehicle(self) -> HeteroAgent | None:
        """The ego agent's object while it is on the road."""
        row = self.traffic.ego_row if getattr(self, "traffic", None) is not None else -1
        if row < 0:
            return None
        uid = int(self.traffic.state.uid[row])
        return next(v for v in self.road.vehicles if v.uid == uid)

    @vehicle.setter
    def vehicle(self, vehicle: HeteroAgent) -> None:
        raise AttributeError("the ego is inserted by config['ego'], not assigned")

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        if not self._ready:
            self._traffic_seed = None
        elif seed is not None:
            self._traffic_seed = int(seed)
        else:  # a fresh seed, as gymnasium does
            self._traffic_seed = int(np.random.SeedSequence().generate_state(1)[0])
        return super().reset(seed=seed, options=options)

    def _reset(self) -> None:
        c = self.config
        self.traffic = Traffic(c, self._traffic_seed or 0, color_of=agent_color)
        self.road = HeteroRoad(make_network(c["road_length"], c["road_width"], int(c["lanes"]), c["sidewalk_width"]),
                              self.traffic)
        self.traffic.road = self.road
        self.warmup_s = 0.0
        self._ego_pending = c["ego"] is not None
        self.ego_collided = False
        if self._traffic_seed is None:
            return  # the reset inside AbstractEnv.__init__: the road stays empty until reset()
        self.traffic.prefill()
        n_warm = int(round(c["warmup"] * self.sim_frequency))
        for _ in range(n_warm):
            self.traffic.step(1.0 / self.sim_frequency)
        self.warmup_s = self.traffic.time
        self.traffic.emergency_stops = 0  # count from the end of warm-up
        if c.get("events"):
            self.traffic.script = EventScript(list(c["events"]), self.traffic.time)
        self._maybe_insert_ego()

    @property
    def sim_frequency(self) -> float:
        return float(self.config["simulation_frequency"])

    @property
    def clock(self) -> float:
        """Seconds since the end of warm-up."""
        return self.traffic.time - self.warmup_s

    def _maybe_insert_ego(self) -> None:
        ego = self.config["ego"]
        if self._ego_pending and self.clock >= float(ego.get("insert_at", 0.0)) - 1e-9:
            if self.traffic.insert_ego(AgentType.parse(ego.get("type", "car")), float(ego.get("speed", 8.0))):
                self._ego_pending = False

    def restart_ego(self) -> None:
        """Take the ego off the road and let it enter again as after warm-up; traffic runs on, the clock restarts."""
        s = self.traffic.state
        if s.is_ego.any():
            s.keep(~s.is_ego)
        self.warmup_s = self.traffic.time
        self._ego_pending = self.config["ego"] is not None
        self.ego_collided = False
        self._maybe_insert_ego()

    def advance(self, n_steps: int, command: tuple[float, float] | None = None) -> list[tuple[str, str, float]]:
        """Run n_steps dynamics steps with the ego command held; returns [(event kind, agent id, clock s)]."""
        events = []
        dt = 1.0 / self.sim_frequency
        for _ in range(n_steps):
            ego_cmd = command if self.traffic.ego_row >= 0 else None
            events += [(k, a, self.clock + dt) for k, a in self.traffic.step(dt, ego_cmd)]
            self._maybe_insert_ego()
            hit = self.ego_overlaps()
            if hit:
                self.ego_collided = True
                events += [("collision", "ego", self.clock)] + [("collision_with", h, self.clock) for h in hit]
            self.steps += 1
        return events

    def ego_overlaps(self) -> list[str]:
        """Ids of the agents whose footprint overlaps the ego's now (oriented boxes)."""
        s, e = self.traffic.state, self.traffic.ego_row
        if e < 0 or s.n < 2:
            return []
        dx, dy = s.x - s.x[e], s.y - s.y[e]
        # Boxes overlap only when their centres are within the sum of their half-diagonals: test only those.
        reach = 0.5 * np.hypot(s.length, s.width) + 0.5 * np.hypot(s.length[e], s.width[e]) + 1e-6
        near = np.flatnonzero((np.abs(dx) < 15.0) & (dx * dx + dy * dy <= reach * reach) & ~s.is_ego)
        if near.size == 0:
            return []
        h = s.headings()
        hit = overlaps_with(s.x, s.y, np.cos(h), np.sin(h), s.length, s.width, near, e)  # the separating-axis test
        return s.agent_id[near[hit]].tolist()

    def step(self, action: np.ndarray | None = None) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """As highway-env's step, but traffic also runs with no ego (then action is ignored)."""
        self.time += 1.0 / self.config["policy_frequency"]
        self._simulate(action)
        obs = self.observation_type.observe()
        return obs, self._reward(action), self._is_terminated(), self._is_truncated(), self._info(obs, action)

    def _simulate(self, action: np.ndarray | None = None) -> None:
        command = None if action is None else (float(action[0]), float(action[1]))
        n = max(1, int(round(self.sim_frequency / self.config["policy_frequency"])))
        self.last_events = self.advance(n, command)

    def view_centre(self) -> np.ndarray:
        e = self.traffic.ego_row
        if e >= 0:
            return np.array([self.traffic.state.x[e], 0.0])
        return np.array([0.5 * self.config["road_length"], 0.0])

    # ------------------------------------------------------------------ episode
    def _reward(self, action: np.ndarray) -> float:
        e = self.traffic.ego_row
        if self.ego_collided:
            return -1.0
        return 0.0 if e < 0 else float(self.traffic.state.vx[e] / self.config["speed_limit"])

    def _is_terminated(self) -> bool:
        return bool(self.ego_collided)

    def _is_truncated(self) -> bool:
        return self.clock >= float(self.config["duration"]) - 1e-9

    def _info(self, obs: np.ndarray, action: Any = None) -> dict[str, Any]:
        e = self.traffic.ego_row
        return {"speed": float(self.traffic.state.vx[e]) if e >= 0 else 0.0, "crashed": bool(self.ego_collided),
                "agents": int(self.traffic.state.n), "time": float(self.clock)}

    # ------------------------------------------------------------------ drawing
    def render(self) -> np.ndarray | None:
        """(screen_height, screen_width, 3) uint8, +y (left of travel) up; works headless."""
        if self.render_mode != "rgb_array":
            return super().render()
        if self.viewer is None:
            self.viewer = HeteroViewer(self)
        self.viewer.display()
        return np.ascontiguousarray(self.viewer.get_image()[::-1])  # pygame's y points down


__all__ = ["AGENT_CLASSES", "PARAMS", "HeteroRoad", "HeteroHighwayEnv", "make_network"]
