"""Scripted events of the SUMO backend (the scenario's `[[events]]`, `scenario.EventSpec`).

As on the highway backend (simharness/sim/highway/events.py): each event places its actors relative
to the ego at `at` seconds after the ego's start, removes the background vehicles their footprints
would overlap, and from then on moves them by script alone: hold speed and line until `delay` seconds
after `at`, then the manoeuvre. With a `lead`, placement is `lead` s earlier and further ahead by what
the ego, keeping its speed, closes on the actor in that time. Scripted actors take no notice of anyone,
the ego included, so after placement what they do is a function of time only; their whole state lives
in this object, which a fork of the worker process copies (`SumoProcess.branch`), so the exact oracle's
branches see it exactly.

An actor is a SUMO vehicle of its type (speed mode 0, no lane changes) moved every SUMO step with
`moveToXY` (keepRoute 2: anywhere on the road), so the background's sub-lane models see it as any
other road user. Coordinates: the ego's entry carriageway frame (s along its direction, m; lat from
its centre line, m, + left; psi, heading relative to its direction, rad), the ego's straight route
through an intersection staying in that frame.

Kinds (placement: ego front s_f, centre line lat_e, speed v_e at `at`; the actor's near end at
s_f + ahead + ahead_time * v_e):
- brake, cut_in, merge, pull_out: as on the highway backend (pull_out: the actor against the kerb on
  the side of `side`); they move sideways towards lat_e + target (vehicles at most MAX_SLIP of their
  forward speed) while braking or accelerating towards `end_speed`;
- step_out: a pedestrian at the kerb on the side of `side`, a stopped bus just behind it; it then
  walks at `lateral_speed` across the whole road (both carriageways of a two-way road);
- turn_across: an oncoming actor (heading against the ego) at lat_e + side, kept on the opposite
  carriageway of a two-way road; after `delay` it turns across the ego's path on a quarter circle
  that ends heading straight across at the ego's line + `target` (the ego's line when the turn
  starts), then goes on straight until it has left the road.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from simharness.scenario import EVENT_ACTORS
from simharness.scene import DEFAULT_FOOTPRINT, AgentType
from simharness.sim.sumo.net import Carriageway

CLEAR_LONG = 2.0  # m kept free ahead of and behind a placed actor (background vehicles there are removed)
CLEAR_LAT = 0.3  # m kept free beside it
KERB_GAP = 0.1  # m between an actor at the kerb and the carriageway edge
MAX_SLIP = 0.8  # a scripted vehicle moves sideways at most this share of its forward speed (about 39 degrees)
PREFIX = "ev"  # SUMO ids "ev<event>.<k>" (k = 0 the actor, 1 the stopped bus of step_out)
EgoPose = tuple[float, float, float, float]  # front s (m), centre lat (m), length (m), speed (m/s): carriageway frame


@dataclasses.dataclass
class Actor:
    """One scripted road user: its SUMO id, type, footprint (m) and kinematic state in the carriageway frame."""

    vid: str
    agent_type: AgentType
    length: float
    width: float
    s: float  # m along the carriageway, centre
    lat: float  # m from its centre line, + left
    v: float  # m/s forward speed (along psi)
    psi: float  # rad, heading of travel relative to the carriageway direction
    vlat: float = 0.0  # m/s sideways (slip) on top of the forward motion
    gone: bool = False  # left the road, or SUMO removed it

    @property
    def heading(self) -> float:
        """Heading of motion relative to the carriageway (rad)."""
        return self.psi + math.atan2(self.vlat, max(abs(self.v), 1e-6)) if self.v > 1e-6 or self.vlat == 0 else \
            self.psi + math.copysign(math.pi / 2, self.vlat)

    @property
    def speed(self) -> float:
        return math.hypot(self.v, self.vlat)


@dataclasses.dataclass
class _Running:
    """One event's progress: its spec, actors (the manoeuvring one first), when it was placed, its goal."""

    spec: dict[str, Any]
    actors: list[Actor] = dataclasses.field(default_factory=list)
    placed_at: float = math.nan
    goal: float = math.nan  # lat (m) or, for turn_across, the final psi (rad); set when the manoeuvre starts
    radius: float = math.nan  # m, turn_across only
    done: bool = False  # placement attempted (placed, or skipped because the ego was absent)


class EventScript:
    """The scripted events of one SUMO run, stepped once per SUMO step before `simulationStep`.

    events: EventSpec fields as dicts; cw: the ego's entry carriageway (the frame); road_left: lat (m) of
    the road's left edge in that frame (the far edge of a two-way road); t0: SUMO time (s) of the ego's
    start, from which event times count.
    """

    def __init__(self, events: list[dict[str, Any]], cw: Carriageway, road_left: float, route: str,
                 t0: float) -> None:
        self.events = [_Running(dict(e)) for e in events]
        self.cw, self.road_left, self.route, self.t0 = cw, road_left, route, t0
        self.half = cw.width / 2
        self._angle0 = math.atan2(cw.direction[1], cw.direction[0])

    def actors(self) -> list[Actor]:
        return [a for ev in self.events for a in ev.actors]

    # ------------------------------------------------------------------ frame
    def to_world(self, s: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """(n,) along, (n,) lateral (m, carriageway frame) -> (n, 2) world xy."""
        c = self.cw
        return c.start + np.multiply.outer(s, c.direction) + np.multiply.outer(c.centre_offset - lat, c.right)

    def from_world(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) world xy -> (n,) along, (n,) lateral (m, carriageway frame)."""
        rel = xy - self.cw.start
        return rel @ self.cw.direction, self.cw.centre_offset - rel @ self.cw.right

    # ------------------------------------------------------------------ stepping
    def step(self, ls: Any, now: float, dt: float, ego: Callable[[], EgoPose | None]) -> None:
        """Place due actors, advance the placed ones by `dt` and move them in SUMO (before its next step).

        now: SUMO time (s); ego: the ego's pose now in the carriageway frame, or None if it is absent
        (called only when an event is placed or its manoeuvre starts).
        """
        clock = now - self.t0
        for i, ev in enumerate(self.events):
            if not ev.done and clock >= float(ev.spec["at"]) - float(ev.spec["lead"]) - 1e-9:
                ev.done = True
                pose = ego()
                if pose is not None:
                    self._place(ls, i, ev, clock, pose)
                    continue
            if not ev.actors or clock <= ev.placed_at + 1e-9:
                continue
            main = ev.actors[0]
            acts = ev.placed_at + float(ev.spec["lead"]) + float(ev.spec["delay"])
            manoeuvring = clock >= acts - 1e-9 and not main.gone
            if manoeuvring and not np.isfinite(ev.goal):
                self._goal(ev, main, ego())
            for k, a in enumerate(ev.actors):
                if a.gone:
                    continue
                if k == 0 and manoeuvring:
                    self._manoeuvre(ev, a, dt)
                else:  # hold speed and line (the bus of step_out stands)
                    a.vlat = 0.0
                    a.s += a.v * math.cos(a.psi) * dt
                    a.lat += a.v * math.sin(a.psi) * dt
                self._move(ls, a)

    def _place(self, ls: Any, i: int, ev: _Running, clock: float, ego: EgoPose) -> None:
        sp, kind = ev.spec, ev.spec["kind"]
        s_f, lat_e, _, v_e = ego
        actor_type = AgentType.parse(sp["actor"] or EVENT_ACTORS[kind])
        al, aw = DEFAULT_FOOTPRINT[actor_type]
        near = s_f + float(sp["ahead"]) + float(sp["ahead_time"]) * v_e
        speed = v_e if sp["speed"] < 0 else float(sp["speed"])
        kerb = 1.0 if sp["side"] > 0 else -1.0
        lim = self.half - 0.5 * aw - KERB_GAP
        placed: list[tuple[AgentType, float, float, float, float]] = []  # (type, s, lat, speed, psi)
        if kind == "step_out":
            bl = DEFAULT_FOOTPRINT[AgentType.BUS][0]
            bw = DEFAULT_FOOTPRINT[AgentType.BUS][1]
            near = max(near, s_f + bl + 1.0)  # the bus must fit in front of the ego
            placed.append((actor_type, near + 0.5 * al, kerb * lim, 0.0, 0.0))
            placed.append((AgentType.BUS, near - 0.5 - 0.5 * bl, kerb * (self.half - 0.5 * bw - KERB_GAP), 0.0, 0.0))
        elif kind == "pull_out":
            placed.append((actor_type, near + 0.5 * al, kerb * lim, speed if sp["speed"] >= 0 else 0.0, 0.0))
        elif kind == "turn_across":  # oncoming: on the opposite carriageway of a two-way road
            lo = self.half + 0.5 * aw + KERB_GAP if self.road_left > self.half else -lim
            lat = float(np.clip(lat_e + sp["side"], lo, self.road_left - 0.5 * aw - KERB_GAP))
            placed.append((actor_type, near + 0.5 * al, lat, speed, math.pi))
        else:
            placed.append((actor_type, near + 0.5 * al, float(np.clip(lat_e + sp["side"], -lim, lim)), speed, 0.0))
        for k, (t, s, lat, v, psi) in enumerate(placed):
            s += float(sp["lead"]) * (v_e - v * math.cos(psi))  # what the ego, keeping its speed, closes in the lead
            length, width = DEFAULT_FOOTPRINT[t]
            a = Actor(f"{PREFIX}{i}.{k}", t, float(length), float(width), float(s), float(lat), float(v), psi)
            self._clear(ls, a)
            ls.vehicle.add(a.vid, self.route, typeID=f"{t.label}__1", depart="now", departLane="0",
                           departSpeed="0")
            ls.vehicle.setSpeedMode(a.vid, 0)
            ls.vehicle.setLaneChangeMode(a.vid, 0)
            self._move(ls, a)
            ev.actors.append(a)
        ev.placed_at = clock

    def _clear(self, ls: Any, a: Actor) -> None:
        """Remove the background vehicles (not the ego, crossing pedestrians or actors) the actor's box would crowd."""
        ids = [v for v in ls.vehicle.getIDList() if v != "ego" and not v.startswith((PREFIX, "xped"))]
        if not ids:
            return
        front = np.array([ls.vehicle.getPosition(v) for v in ids], float).reshape(len(ids), 2)
        angle = np.radians([ls.vehicle.getAngle(v) for v in ids])
        length = np.array([ls.vehicle.getLength(v) for v in ids])
        width = np.array([ls.vehicle.getWidth(v) for v in ids])
        centre = front - np.stack([np.sin(angle), np.cos(angle)], -1) * (length[:, None] / 2)
        s, lat = self.from_world(centre)
        along = 0.5 * (a.length if abs(math.cos(a.psi)) > 0.5 else a.width) + CLEAR_LONG
        across = 0.5 * (a.width if abs(math.cos(a.psi)) > 0.5 else a.length) + CLEAR_LAT
        crowd = (np.abs(s - a.s) < along + 0.5 * length) & (np.abs(lat - a.lat) < across + 0.5 * width)
        for k in np.flatnonzero(crowd):
            ls.vehicle.remove(ids[k])

    # ------------------------------------------------------------------ the manoeuvre
    def _goal(self, ev: _Running, a: Actor, ego: EgoPose | None) -> None:
        """Fix the manoeuvre's goal when it starts: a lateral offset (m), or turn_across's final heading."""
        sp = ev.spec
        if sp["kind"] == "step_out":  # across the whole road, onto the far sidewalk
            ev.goal = self.road_left + 0.5 if a.lat < 0 else -self.half - 0.5
        elif sp["kind"] == "turn_across":  # the quarter circle ends at the ego's line + target
            end = (ego[1] if ego is not None else a.lat) + float(sp["target"])
            ev.radius = max(abs(a.lat - end), 1.0)
            ev.goal = a.psi + math.copysign(math.pi / 2, a.lat - end)
        else:
            ref = ego[1] if ego is not None else a.lat
            lim = self.half - 0.5 * a.width - KERB_GAP
            ev.goal = float(np.clip(ref + sp["target"], -lim, lim))

    def _manoeuvre(self, ev: _Running, a: Actor, dt: float) -> None:
        """Advance the manoeuvring actor by dt: speed towards end_speed, then its sideways motion or turn."""
        sp = ev.spec
        acc = float(np.clip((float(sp["end_speed"]) - a.v) / dt, -float(sp["decel"]), float(sp["accel"])))
        v0, a.v = a.v, max(a.v + acc * dt, 0.0)
        ds = 0.5 * (v0 + a.v) * dt
        if sp["kind"] == "turn_across":
            if a.psi != ev.goal:  # on the quarter circle: heading turns by distance / radius
                turn = ev.goal - a.psi
                a.psi += math.copysign(min(ds / ev.radius, abs(turn)), turn)
            a.vlat = 0.0
            a.s += ds * math.cos(a.psi)
            a.lat += ds * math.sin(a.psi)
            if a.lat - 0.5 * a.length > self.road_left + 1.0 or a.lat + 0.5 * a.length < -self.half - 1.0:
                a.gone = True  # left the road
            return
        lim = float(sp["lateral_speed"])
        if a.agent_type != AgentType.PEDESTRIAN:  # vehicles steer; they do not slide sideways
            lim = min(lim, MAX_SLIP * max(a.v, 0.0))
        a.vlat = float(np.clip((ev.goal - a.lat) / dt, -lim, lim))
        a.s += ds
        a.lat += a.vlat * dt
        if sp["kind"] == "step_out" and abs(a.lat - ev.goal) < 1e-6:
            a.gone = True  # reached the far sidewalk

    # ------------------------------------------------------------------ SUMO
    def _move(self, ls: Any, a: Actor) -> None:
        """Put the actor's SUMO vehicle at its scripted pose (front bumper, SUMO angle), or remove it when gone."""
        if a.gone:
            if a.vid in ls.vehicle.getIDList():
                ls.vehicle.remove(a.vid)
            return
        h = self._angle0 + a.heading
        centre = self.to_world(np.array(a.s), np.array(a.lat))
        front = centre + 0.5 * a.length * np.array([math.cos(h), math.sin(h)])
        try:
            ls.vehicle.setSpeed(a.vid, a.speed)
            ls.vehicle.moveToXY(a.vid, "", -1, float(front[0]), float(front[1]),
                                math.degrees(math.pi / 2 - h) % 360.0, 2)
        except ls.TraCIException:  # SUMO removed it (it found no road there): it is gone
            a.gone = True

    def override(self, ids: tuple[str, ...], xy: np.ndarray, heading: np.ndarray, sim_heading: np.ndarray,
                 speed: np.ndarray, lateral: np.ndarray) -> None:
        """Record the actors' scripted poses (SUMO boxes follow lanes): centre xy (n, 2) m, heading and
        sim_heading (n,) rad, speed (n,) m/s, lateral (n,) m, all changed in place for the actors among ids."""
        for a in self.actors():
            if a.gone:
                continue
            try:
                i = ids.index(a.vid)
            except ValueError:
                continue
            h = self._angle0 + a.heading
            xy[i] = self.to_world(np.array(a.s), np.array(a.lat))
            heading[i] = sim_heading[i] = math.remainder(h, 2 * math.pi)
            speed[i] = a.speed
            lateral[i] = a.lat
