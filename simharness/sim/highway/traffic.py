"""The traffic on one straight carriageway: spawning, the step, removal, the ego.

`Traffic` owns a `TrafficState` (arrays) and a numpy Generator; each `step`
applies the vectorised rules of `dynamics` to all agents at once.
Vehicles and pedestrians walking along the edge enter at the upstream end
(Poisson arrivals at the configured flows; an arrival waits in a queue until
there is room) and leave at the downstream end; crossing pedestrians appear
on a sidewalk and leave at the other. Agent ids are never reused.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from simharness.scene import AgentType
from simharness.sim.base import DRIFT_FULL_SPEED, ego_lateral_limit
from simharness.sim.highway import dynamics as dyn
from simharness.sim.highway.crossing import crossing_clear
from simharness.sim.highway.decision import choose_offsets
from simharness.sim.highway.dynamics import CROSSING, VEHICLE, WALKING, TrafficState
from simharness.sim.highway.events import EventScript
from simharness.sim.highway.leaders import leaders
from simharness.sim.highway.params import PARAMS
from simharness.sim.highway.room import lateral_room

EDGE_GAP = 0.2  # m kept between a vehicle and the carriageway edge
PED_SPACING = 1.5  # m along the road between two crossing pedestrians at their start
CUT_IN_RANGE = 10.0  # m ahead of the ego's front within which background agents cut in (cut_in setting)
QUEUE_MAX = 200  # arrivals waiting for room; beyond this new arrivals are dropped (and counted)


class Traffic:
    """Agents on a straight carriageway from x = 0 to `length`, y in [-width/2, width/2] (+y left).

    config: the env config (see `HeteroHighwayEnv.default_config`): road_length, road_width, lanes,
    sidewalk_width, speed_limit, demand {type label: veh/h}, crossing_rate, walking_rate (per hour),
    walking_speed, behaviour_spread, speed_dev, lateral_resolution, min_gap_lat, lane_discipline,
    decision_period, ego {type, insert_at, speed, reaction} or None.
    """

    def __init__(self, config: dict[str, Any], seed: int, road: Any = None,
                 color_of: Callable[[AgentType, bool], str] | None = None) -> None:
        self.config = config
        self.road = road
        self.rng = np.random.default_rng(seed)
        self.length = float(config["road_length"])
        self.half_width = 0.5 * float(config["road_width"])
        self.sidewalk = float(config["sidewalk_width"])
        self.speed_limit = float(config["speed_limit"])
        self.min_gap_lat = float(config["min_gap_lat"])
        self.state = TrafficState.empty()
        self.time = 0.0
        self.steps = 0
        self.next_uid = 0
        self.dropped = 0
        self.emergency_stops = 0
        self.queue: list[tuple[int, int]] = []  # (agent type, kind) waiting to enter
        self.ego_reaction = (config.get("ego") or {}).get("reaction", "reactive")
        self._color_of = color_of or (lambda t, ego: "#7f7f7f")
        flows = {AgentType.parse(k): float(v) for k, v in config["demand"].items() if float(v) > 0}
        self.flows = [(int(t), VEHICLE, q) for t, q in sorted(flows.items())]
        if config["walking_rate"] > 0:
            self.flows.append((int(AgentType.PEDESTRIAN), WALKING, float(config["walking_rate"])))
        self.next_arrival = np.array([self.rng.exponential(3600.0 / q) for _, _, q in self.flows])
        self.next_crossing = (self.rng.exponential(3600.0 / config["crossing_rate"])
                              if config["crossing_rate"] > 0 else np.inf)
        self.lane_centres = self._lane_centres()
        self.script: EventScript | None = None  # scripted events (events.py), set by the env after warm-up

    # ------------------------------------------------------------------ lookup
    def row_of(self, uid: int, missing: int | None = None) -> int:
        """Row of an agent by uid (rows are sorted by uid); KeyError, or `missing`, when it left."""
        r = int(np.searchsorted(self.state.uid, uid))
        if r < self.state.n and self.state.uid[r] == uid:
            return r
        if missing is not None:
            return missing
        raise KeyError(f"agent uid {uid} is no longer on the road")

    def headings(self) -> np.ndarray:
        return self.state.headings()

    def color_of(self, agent_type: AgentType, is_ego: bool) -> str:
        return self._color_of(agent_type, is_ego)

    @property
    def ego_row(self) -> int:
        hit = np.flatnonzero(self.state.is_ego)
        return int(hit[0]) if hit.size else -1

    def _lane_centres(self) -> np.ndarray | None:
        lanes = int(self.config["lanes"])
        if lanes < 2 or self.config["lane_discipline"] < 0.5:
            return None
        w = 2 * self.half_width / lanes
        return -self.half_width + w * (np.arange(lanes) + 0.5)

    def _grid(self) -> np.ndarray:
        """(C,) candidate lateral offsets across the carriageway (m)."""
        if self.lane_centres is not None:
            return self.lane_centres
        res = max(float(self.config["lateral_resolution"]), 0.2)
        return np.arange(-self.half_width, self.half_width + 1e-9, res)

    # ------------------------------------------------------------------ new agents
    def _new_columns(self, agent_type: int, kind: int, is_ego: bool = False) -> dict[str, Any]:
        """Per-agent constants for one new agent: footprint, its driver's parameters (behaviour spread)."""
        c = self.config
        t = agent_type
        spread = 0.0 if is_ego else float(c["behaviour_spread"])
        aggr = self.rng.uniform(-1.0, 1.0) * spread  # + aggressive, - conservative
        dev = 0.0 if is_ego else float(c["speed_dev"]) * float(np.clip(self.rng.normal(), -2, 2))
        if t == AgentType.PEDESTRIAN:
            v0 = float(c["walking_speed"]) * (1 + 0.15 * float(np.clip(self.rng.normal(), -2, 2)))
        else:
            v0 = min(PARAMS["v_max"][t], self.speed_limit * PARAMS["speed_factor"][t]) * (1 + dev) * (1 + 0.05 * aggr)
        uid = self.next_uid
        self.next_uid += 1
        return dict(
            uid=uid, agent_id="ego" if is_ego else f"{AgentType(t).label}_{uid}", agent_type=t, kind=kind,
            is_ego=is_ego, length=PARAMS["length"][t], width=PARAMS["width"][t], v0=v0,
            a_max=PARAMS["a_max"][t] * (1 + 0.25 * aggr), b_comf=PARAMS["b_comf"][t],
            headway=PARAMS["headway"][t] * (1 - 0.35 * aggr), s0=PARAMS["s0"][t] * (1 - 0.3 * aggr),
            vy_max=PARAMS["vy_max"][t], switch_margin=0.4 * (1 - 0.6 * aggr), cross_dir=0.0,
        )

    def _place(self, cols: dict[str, Any], x: float, cand_y: np.ndarray) -> tuple[float, float] | None:
        """Lateral offset and speed at which a new agent fits at x without crowding anyone, or None.

        cand_y (C,) m. Needs its standstill gap to every agent ahead in its band (with the lateral
        minimum gap) and the follower's safe gap to it behind; speed as a follower of that band.
        """
        s = self.state
        hx, hy = 0.5 * cols["length"], 0.5 * cols["width"]
        if s.n == 0:
            y = cand_y[int(self.rng.integers(cand_y.size))]
            return float(y), float(cols["v0"])
        ohx, ohy = dyn.half_extents(s.length, s.width, s.headings())
        band = ((s.y - ohy)[None, :] < (cand_y + hy + self.min_gap_lat)[:, None]) & \
               ((s.y + ohy)[None, :] > (cand_y - hy - self.min_gap_lat)[:, None])  # (C, n)
        ahead = (s.x - ohx) - (x + hx)  # (n,) bumper gap to agents ahead
        behind = (x - hx) - (s.x + ohx)
        follower_need = s.s0 + s.vx * s.headway + np.maximum(s.vx - cols["v0"], 0) ** 2 / (2 * s.b_comf)
        ok_each = np.where(ahead >= 0, ahead >= cols["s0"], behind >= follower_need)
        ok_each &= (ahead >= 0) | (behind >= 0)
        feasible = ~(band & ~ok_each[None, :]).any(axis=1)
        if not feasible.any():
            return None
        lead_gap = np.where(band & (ahead >= 0)[None, :], ahead[None, :], np.inf)
        j = np.argmin(lead_gap, axis=1)
        g = lead_gap[np.arange(cand_y.size), j]
        v = np.where(np.isfinite(g), s.vx[j] + np.maximum(g - cols["s0"], 0) / cols["headway"], cols["v0"])
        v = np.minimum(v, cols["v0"])
        score = np.where(feasible, v + self.rng.uniform(0, 1.0, cand_y.size), -np.inf)
        c = int(np.argmax(score))
        return float(cand_y[c]), float(v[c])

    def _vehicle_offsets(self, width: float) -> np.ndarray:
        g = self._grid()
        return g[np.abs(g) + 0.5 * width <= self.half_width - EDGE_GAP]

    def _walk_offsets(self) -> np.ndarray:
        hy = 0.5 * PARAMS["width"][AgentType.PEDESTRIAN]
        return np.array([self.half_width - hy - 0.15, -self.half_width + hy + 0.15])

    def _add(self, cols: dict[str, Any], x: float, y: float, v: float) -> None:
        self.state.append(**cols, x=x, y=y, vx=v if cols["kind"] != CROSSING else 0.0, vy=0.0, y_target=y)

    def try_insert(self, agent_type: int, kind: int, x: float | None = None, is_ego: bool = False,
                   speed: float | None = None) -> bool:
        """Put one agent on the road at x (default: entering at x = 0); False when there is no room."""
        cols = self._new_columns(agent_type, kind, is_ego)
        x = 0.5 * cols["length"] if x is None else x
        cand = self._walk_offsets() if kind == WALKING else self._vehicle_offsets(cols["width"])
        placed = self._place(cols, x, cand)
        if placed is None:
            self.next_uid -= 1  # nothing was created; keep uids dense and deterministic
            return False
        y, v = placed
        self._add(cols, x, y, v if speed is None else min(v, speed))
        return True

    def spawn_crossing(self) -> bool:
        """A pedestrian appears on a sidewalk at a random x and will cross; False if too close to another."""
        x = float(self.rng.uniform(0.05, 0.95) * self.length)
        direction = 1.0 if self.rng.random() < 0.5 else -1.0
        crossing = self.state.kind == CROSSING
        if np.any(np.abs(self.state.x[crossing] - x) < PED_SPACING):
            return False
        cols = self._new_columns(int(AgentType.PEDESTRIAN), CROSSING)
        cols["cross_dir"] = direction
        self._add(cols, x, -direction * self._kerb_offset(), 0.0)
        return True

    def _kerb_offset(self) -> float:
        """|y| of a pedestrian waiting on the sidewalk (m)."""
        return self.half_width + max(0.5 * self.sidewalk, 0.5)

    def prefill(self, density_speed_share: float = 0.6) -> None:
        """Fill the road at each flow's density (flow / speed, speed a share of the desired speed)."""
        todo = []
        for t, kind, q in self.flows:
            v = (float(self.config["walking_speed"]) if kind == WALKING else
                 min(PARAMS["v_max"][t], self.speed_limit * PARAMS["speed_factor"][t]) * density_speed_share)
            todo += [(t, kind)] * int(self.rng.poisson(q / 3600.0 / max(v, 0.5) * self.length))
        for i in self.rng.permutation(len(todo)):  # reset only: one vectorised placement per agent
            t, kind = todo[i]
            self.try_insert(t, kind, x=float(self.rng.uniform(0.0, self.length)))

    def insert_ego(self, agent_type: AgentType, speed: float) -> bool:
        """The ego enters running traffic a quarter of the way along the road, or at the nearest room."""
        steps = np.arange(1, int(0.25 * self.length / 2.5) + 1) * 2.5
        for x in 0.25 * self.length + np.concatenate([[0.0], np.stack([steps, -steps], 1).ravel()]):
            if self.try_insert(int(agent_type), VEHICLE, x=float(x), is_ego=True, speed=speed):
                return True
        return False

    def _arrivals(self) -> None:
        for k, (t, kind, q) in enumerate(self.flows):
            while self.next_arrival[k] <= self.time:
                if len(self.queue) < QUEUE_MAX:
                    self.queue.append((t, kind))
                else:
                    self.dropped += 1
                self.next_arrival[k] += self.rng.exponential(3600.0 / q)
        waiting, self.queue = self.queue, []
        blocked: set[tuple[int, int]] = set()
        for t, kind in waiting:  # per arrival, not per agent pair: each attempt is vectorised
            if (t, kind) in blocked or not self.try_insert(t, kind):
                blocked.add((t, kind))  # keep arrival order within a type
                self.queue.append((t, kind))
        while self.next_crossing <= self.time:
            self.spawn_crossing()
            self.next_crossing += self.rng.exponential(3600.0 / self.config["crossing_rate"])

    # ------------------------------------------------------------------ the step
    def step(self, dt: float, ego_command: tuple[float, float] | None = None) -> list[tuple[str, str]]:
        """Advance all agents by dt seconds. ego_command: (acceleration m/s^2, lateral velocity m/s, + left)
        or None (the ego drives like the background). Returns [(event kind, agent id)]."""
        self._arrivals()
        script = self.script.commands(self, dt) if self.script is not None else None
        s = self.state
        events: list[tuple[str, str]] = []
        if s.n:
            events = self._move(s, dt, ego_command, script)
        self._remove_departed()
        self.time += dt
        self.steps += 1
        return events

    def _ignores_ego(self, s: TrafficState) -> tuple[bool, bool]:
        """Whether background agents leave the ego out of their leader search and out of their side windows."""
        if self.ego_reaction not in ("ignore", "cut_in") or not s.is_ego.any():
            return False, False
        return self.ego_reaction == "ignore", True

    def _move(self, s: TrafficState, dt: float, ego_command: tuple[float, float] | None,
              script: tuple[np.ndarray, np.ndarray] | None = None) -> list[tuple[str, str]]:
        """script: (acceleration, lateral speed) (n,) of scripted actors, nan for everyone else."""
        n = s.n
        commanded = s.is_ego & (ego_command is not None)
        scripted = np.zeros(n, bool) if script is None else np.isfinite(script[0])
        fixed = commanded | scripted  # driven from outside the traffic model: no clamps, no own decisions
        any_commanded, any_scripted = bool(commanded.any()), bool(scripted.any())
        heading = s.headings()
        hx, hy = dyn.half_extents(s.length, s.width, heading)
        ignore_lon, ignore_lat = self._ignores_ego(s)
        order = np.argsort(s.x)  # the pair searches scan along x

        ped = np.flatnonzero(s.kind == CROSSING)
        walking_now = np.zeros(n, bool)
        if ped.size:
            walking_now[ped] = crossing_clear(ped, s.x, s.y, hx, hy, s.vx, s.v0, s.s0, s.b_comf, s.cross_dir,
                                              s.kind == CROSSING, s.is_ego, ignore_lon, self.half_width)
        lo, hi = dyn.lateral_claims(s, hy, walking_now)

        # Longitudinal: IDM on the lane-free leader, then a hard clamp that keeps every gap open.
        leader, gap = leaders(order, s.x, s.y, hx, hy, lo, hi, s.is_ego, ignore_lon, 0.5 * self.min_gap_lat)
        acc = dyn.idm_acceleration(s.vx, s.v0, s.a_max, s.b_comf, s.headway, s.s0, gap, s.vx[leader])
        if any_commanded:
            a_ego = float(np.clip(ego_command[0], -B_EGO, PARAMS["a_max"][s.agent_type[commanded][0]]))
            acc = np.where(commanded, a_ego, acc)
        if any_scripted:
            acc = np.where(scripted, script[0], acc)
        v_max = PARAMS["v_max"][s.agent_type]
        v_new = dyn.clip(s.vx + acc * dt, 0.0, v_max)
        v_new = dyn.clamp_to_leaders(v_new, leader, gap, dt, fixed, s.kind == CROSSING)
        hard = (s.vx - v_new > dyn.B_EMERGENCY * dt + 1e-9) & ~fixed
        events = [("emergency_stop", str(a)) for a in s.agent_id[hard]]
        self.emergency_stops += int(hard.sum())

        # Lateral: targets chosen by the agents, speeds limited by the room beside them.
        ego_gap = self.min_gap_lat if self.ego_reaction == "cut_in" else -np.inf  # cut_in: side by side only
        room_l, room_r = lateral_room(order, s.x, s.y, hx, hy, s.vx, s.s0, s.is_ego, ignore_lat, ego_gap)
        self._decide_targets(s, order, hx, hy, lo, hi, ignore_lon, room_l, room_r, fixed, dt)
        speed_share = dyn.clip(s.vx / DRIFT_FULL_SPEED, 0.0, 1.0)  # no sideways motion without forward speed
        vy_lim = s.vy_max * speed_share
        vy_des = dyn.clip(dyn.LAT_GAIN * (s.y_target - s.y), -vy_lim, vy_lim)
        vy = s.vy + dyn.clip(vy_des - s.vy, -dyn.LAT_ACC * dt, dyn.LAT_ACC * dt)
        vy = np.where(s.kind == CROSSING, walking_now * s.cross_dir * s.v0, np.where(s.kind == WALKING, 0.0, vy))
        if any_commanded:
            # Bounded by the forward speed at the step's end as well: braking to a stop while edging over would
            # otherwise turn the ego's body (heading = direction of motion) by up to 90 degrees.
            ego_lim = ego_lateral_limit(s.vy_max, s.vx, v_new)
            vy = np.where(commanded, np.clip(ego_command[1], -ego_lim, ego_lim), vy)
        if any_scripted:
            vy = np.where(scripted, script[1], vy)
        move = vy * dt
        up = np.maximum(0.0, 0.5 * (room_l - self.min_gap_lat))
        down = np.maximum(0.0, 0.5 * (room_r - self.min_gap_lat))
        is_veh = s.kind == VEHICLE
        if any_commanded:
            edge_up = np.maximum(0.0, self.half_width - EDGE_GAP * ~commanded - (s.y + hy))
            edge_down = np.maximum(0.0, self.half_width - EDGE_GAP * ~commanded + (s.y - hy))
            up = np.where(commanded, edge_up, np.where(is_veh, np.minimum(up, edge_up), up))
            down = np.where(commanded, edge_down, np.where(is_veh, np.minimum(down, edge_down), down))
        else:  # the same values: nobody has the ego's edge allowance
            edge = self.half_width - EDGE_GAP
            up = np.where(is_veh, np.minimum(up, np.maximum(0.0, edge - (s.y + hy))), up)
            down = np.where(is_veh, np.minimum(down, np.maximum(0.0, edge + (s.y - hy))), down)
        if any_scripted:
            up, down = np.where(scripted, np.inf, up), np.where(scripted, np.inf, down)  # the script keeps them on
        move = dyn.clip(move, -down, up)
        turning = (s.kind != CROSSING) & ~fixed
        move = np.where(turning, dyn.safe_lateral_moves(move, v_new, s.length, s.width, hy, up, down, dt), move)

        s.x = s.x + v_new * dt
        s.y = s.y + move
        s.vx = v_new
        s.vy = move / dt
        return events

    def _decide_targets(self, s: TrafficState, order: np.ndarray, hx: np.ndarray, hy: np.ndarray, lo: np.ndarray,
                        hi: np.ndarray, ignore_ego: bool, room_l: np.ndarray, room_r: np.ndarray, commanded: np.ndarray,
                        dt: float) -> None:
        """Re-choose the lateral target of a rotating share of the vehicles (each every decision_period)."""
        every = max(1, int(round(float(self.config["decision_period"]) / dt)))
        rows = np.flatnonzero((s.kind == VEHICLE) & ~commanded & (s.uid % every == self.steps % every))
        if rows.size == 0:
            return
        kerb_bias = np.where(s.v0[rows] < 0.6 * self.speed_limit, 1.5, 0.0)  # slow vehicles keep to the kerb
        cut_in, ego_y, ego_hy = self._cut_in_rows(s, rows, hy)
        s.y_target[rows] = choose_offsets(
            order, rows, self._grid(), self.lane_centres is None, s.x, s.y, s.y_target, hx, hy, lo, hi, s.vx, s.v0,
            s.s0, s.headway, s.b_comf, s.switch_margin, room_l, room_r, s.is_ego, ignore_ego, kerb_bias, cut_in, ego_y,
            ego_hy, self.half_width, EDGE_GAP, self.min_gap_lat)

    def _cut_in_rows(self, s: TrafficState, rows: np.ndarray, hy: np.ndarray) -> tuple[np.ndarray, float, float]:
        """Which deciding rows (R,) bool get the cut-in bonus in the ego's band, and that band (centre, half width
        m): in the cut_in setting, agents just ahead of the ego merge into its band the way a driver who has just
        overtaken does, without yielding to it."""
        e = self.ego_row
        if self.ego_reaction != "cut_in" or e < 0:
            return np.zeros(rows.size, bool), 0.0, 0.0
        lead = (s.x[rows] - 0.5 * s.length[rows]) - (s.x[e] + 0.5 * s.length[e])
        return (lead > 0) & (lead < CUT_IN_RANGE) & ~s.is_ego[rows], float(s.y[e]), float(hy[e])

    def _remove_departed(self) -> None:
        s = self.state
        gone = (s.x - 0.5 * s.length > self.length) & (s.kind != CROSSING)
        gone |= (s.kind == CROSSING) & (s.cross_dir * s.y > self._kerb_offset())
        if gone.any():
            s.keep(~gone)


B_EGO = 8.0  # m/s^2: hardest braking an ego command may ask for
