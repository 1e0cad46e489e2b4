"""Where the ego enters, and the "ignore" ego: a harness-integrated agent that SUMO never sees.

With `ego.reaction = "ignore"` no background agent may react to the ego, which SUMO cannot express
per vehicle; so the ego is not a SUMO vehicle at all. It moves along its entry carriageway's line
(straight on through an intersection) with the type's kinematic limits: by the command, or, with
no command, by IDM car-following on the agents ahead in its lateral band (the background-model
reference). Its overlaps with other agents are reported as collision events.
"""

from __future__ import annotations

import numpy as np

from simharness.metrics.collisions import boxes_overlap
from simharness.scenario import ScenarioSpec
from simharness.scene import DEFAULT_FOOTPRINT, AgentType
from simharness.sim.base import EGO_MAX_DECEL, EgoCommand, ego_lateral_limit
from simharness.sim.sumo.net import Carriageway, Network

IDM_HEADWAY = 1.2  # s
IDM_GAP = 2.0  # m
IDM_DELTA = 4.0
# m/s^2: the ego slows its sideways motion into the edge of its carriageway no harder than this. SUMO's lanes carry
# one direction, so the ego cannot cross the centre line of a two-way road that its planner, seeing a lane-less
# road, may aim across; it eases into that edge instead of stopping dead there.
EDGE_DECEL = 1.5


def lateral_move(command: float, lat: float, half: float, limit: float, dt: float) -> float:
    """The ego's lateral offset (m, + left) after `dt` s from `lat` within [-half, half]: the commanded lateral speed
    (m/s) clipped to +-limit (`sim.base.ego_lateral_limit`), slowed to stop at the edge it heads for at `EDGE_DECEL`.
    Both SUMO egos (the one SUMO moves, the ghost) step sideways by this."""
    lat_v = float(np.clip(command, -limit, limit))
    room = max(half - lat if lat_v > 0 else half + lat, 0.0)
    lat_v = float(np.sign(lat_v) * min(abs(lat_v), np.sqrt(2.0 * EDGE_DECEL * room)))
    return float(np.clip(lat + lat_v * dt, -half, half))


def ego_start(net: Network) -> tuple[Carriageway, float]:
    """Entry carriageway and distance along it where the ego enters (a fifth in, at most 60 m)."""
    cw = net.entries[0]
    return cw, float(min(0.2 * cw.length, 60.0))


def free_lateral(cw: Carriageway, pos: float, xy: np.ndarray, width: np.ndarray, own_width: float) -> float:
    """Lateral offset (m, + left) at `pos` along `cw` with the most clearance to agents within 15 m.

    xy (n, 2) world centres, width (n,) of the agents already there.
    """
    rel = xy - cw.start
    s, lat = rel @ cw.direction, cw.centre_offset - rel @ cw.right
    half = cw.width / 2 - own_width / 2
    cand = np.linspace(-half, half, 31)
    near = np.abs(s - pos) < 15.0
    if not near.any():
        return 0.0
    gap = np.abs(cand[:, None] - lat[near][None]) - width[near][None] / 2  # (31, m)
    return float(cand[np.argmax(gap.min(1))])


def entry_speed(cw: Carriageway, pos: float, lat: float, xy: np.ndarray, length: np.ndarray, width: np.ndarray,
                speed: np.ndarray, own_length: float, own_width: float, wanted: float, dt: float) -> float:
    """The ego's speed (m/s) on entering at `pos` along `cw`, lateral offset `lat`: `wanted`, unless at that speed it
    could not stop behind the nearest agent ahead in its lateral band (that agent holding its speed; one frame of
    `dt` s before the ego brakes, then EGO_MAX_DECEL). Then it enters at a speed it can follow at: the agent's, or
    what the gap less IDM_GAP m covers in IDM_HEADWAY s, whichever is faster. Why: a collision that no driving could
    avoid is the placement's doing, not the ego's; short of that, entering fast into dense traffic is the scenario.

    xy (n, 2) world centres, length, width, speed (n,) of the agents already there.
    """
    rel = xy - cw.start
    s, la = rel @ cw.direction, cw.centre_offset - rel @ cw.right
    gap = s - length / 2 - (pos + own_length / 2)  # (n,) m, the ego's front to each one's rear
    ahead = (np.abs(la - lat) < (width + own_width) / 2) & (gap > -0.5)
    if not ahead.any():
        return wanted
    k = np.flatnonzero(ahead)[np.argmin(gap[ahead])]
    closing = wanted - float(speed[k])
    if closing <= 0 or closing * dt + closing**2 / (2 * EGO_MAX_DECEL) < gap[k]:
        return wanted
    return float(min(wanted, max(speed[k], (gap[k] - IDM_GAP) / IDM_HEADWAY)))


class GhostEgo:
    """Kinematic ego on a straight line: position s (m) along `cw`, lateral offset (m, + left), speed."""

    def __init__(self, spec: ScenarioSpec, cw: Carriageway, pos: float, agent_type: AgentType) -> None:
        from simharness.sim.sumo.demand import KINEMATICS

        self.cw, self.s, self.lat, self.v = cw, pos, 0.0, spec.ego.speed
        self.type = agent_type
        _, _, self.vmax, self.accel, self.decel, _, self.vlat, _ = KINEMATICS[agent_type]
        self.length, self.width = DEFAULT_FOOTPRINT[agent_type]
        self.heading = float(np.arctan2(cw.direction[1], cw.direction[0]))
        self.lat_v = 0.0
        self.new_contacts: list[str] = []
        self._contacts: set[str] = set()
        self._placed = False

    def _frame_coords(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) world centres -> (n,) along-line and (n,) lateral (+ left) coordinates of the ego's line."""
        rel = xy - self.cw.start
        return rel @ self.cw.direction, self.cw.centre_offset - rel @ self.cw.right

    def place(self, xy: np.ndarray, length: np.ndarray, width: np.ndarray, speed: np.ndarray, dt: float) -> None:
        """On entry: the lateral spot with the most clearance to agents within 15 m along the road, at a speed from
        which it can stop behind the agent ahead there (`entry_speed`)."""
        self.lat = free_lateral(self.cw, self.s, xy, width, self.width)
        self.v = entry_speed(self.cw, self.s, self.lat, xy, length, width, speed, self.length, self.width, self.v, dt)
        self._placed = True

    def advance(self, command: EgoCommand | None, dt: float, xy: np.ndarray, heading: np.ndarray,
                speed: np.ndarray, length: np.ndarray, width: np.ndarray, ids: np.ndarray) -> None:
        """One recorded frame of motion given the other agents now: xy (n, 2); heading, speed, length, width,
        ids (n,)."""
        if not self._placed:
            self.place(xy, length, width, speed, dt)
        s, lat = self._frame_coords(xy)
        if command is None:  # IDM on the nearest agent ahead that overlaps the ego's lateral band
            band = np.abs(lat - self.lat) < (width + self.width) / 2
            gaps = s - length / 2 - (self.s + self.length / 2)
            ahead = band & (gaps > -0.5)
            a = self.accel * (1 - (self.v / self.vmax) ** IDM_DELTA)
            if ahead.any():
                k = np.flatnonzero(ahead)[np.argmin(gaps[ahead])]
                dv = self.v - speed[k]
                s_star = IDM_GAP + self.v * IDM_HEADWAY + self.v * dv / (2 * np.sqrt(self.accel * self.decel))
                a -= self.accel * (max(s_star, 0.0) / max(gaps[k], 0.1)) ** 2
            lat_v = 0.0
        else:
            a, lat_v = command.acceleration, command.lateral_velocity
        a = float(np.clip(a, -2.0 * self.decel, self.accel))
        v_new = float(np.clip(self.v + a * dt, 0.0, self.vmax))
        lim = float(ego_lateral_limit(self.vlat, self.v, v_new))
        self.s += 0.5 * (self.v + v_new) * dt
        self.v = v_new
        new_lat = lateral_move(lat_v, self.lat, self.cw.width / 2 - self.width / 2, lim, dt)
        self.lat_v = (new_lat - self.lat) / dt
        self.lat = new_lat
        self.heading = float(np.arctan2(self.cw.direction[1], self.cw.direction[0]) +
                             np.arctan2(self.lat_v, max(self.v, 1e-3)))
        # Overlaps with the background (first frame of each contact only).
        me = self.state()
        hit = boxes_overlap(me["xy"][None], np.full(len(xy), me["heading"]), np.full(len(xy), self.length),
                            np.full(len(xy), self.width), xy, heading, length, width) if len(xy) else np.zeros(0, bool)
        now = set(ids[hit].tolist())
        self.new_contacts = sorted(now - self._contacts)
        self._contacts = now

    def state(self) -> dict[str, float | np.ndarray]:
        c = self.cw
        xy = c.start + c.direction * self.s + c.right * (c.centre_offset - self.lat)
        line = float(np.arctan2(c.direction[1], c.direction[0]))
        return {"xy": xy, "heading": self.heading, "sim_heading": line, "speed": float(np.hypot(self.v, self.lat_v)),
                "lateral": self.lat, "type": float(int(self.type)), "length": self.length, "width": self.width}
