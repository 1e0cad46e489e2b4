"""Scripted events of the highway backend (the scenario's `[[events]]`, `scenario.EventSpec`).

Each event places an actor relative to the ego at `at` seconds after warm-up (step_out and pull_out
also a bus stopped at the kerb), removes the background agents its footprint would overlap, and from
then on drives it by script alone: it holds its speed and line until `delay` seconds after `at`, then runs its
manoeuvre (brake; move sideways towards a target offset while braking or accelerating towards
`end_speed`). Scripted actors take no notice of anyone, the ego included, so after placement what
they do is a function of time only: any oracle that branches the simulation sees it exactly, and
predictors that extrapolate the past do not.

Placement (ego front x_f, centre line y_e, speed v_e at `at`): the actor's rear at
x_f + ahead + ahead_time * v_e, its centre at y_e + side (kept on the carriageway). With a `lead`, it is
placed `lead` s earlier and lead * (v_e - its speed) further ahead: an ego that keeps its speed meets the
same geometry at `at`, and one that anticipates has had the actor in view for `lead` s. step_out and
pull_out put the bus (pull_out: its actor, a bus unless `actor` names another, by its own width)
against the kerb on the side of `side` (right when 0); step_out puts its
pedestrian there on the kerb line, the stopped bus just behind it (between it and the ego: the
pedestrian goes at least a bus length + 1 m ahead), and the pedestrian then crosses the whole carriageway.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from simharness.scene import AgentType
from simharness.sim.highway.dynamics import VEHICLE
from simharness.sim.highway.params import PARAMS

ACTORS = {"brake": "truck", "cut_in": "motorcycle", "step_out": "pedestrian", "pull_out": "bus",
          "merge": "rickshaw"}  # as scenario.EVENT_ACTORS: the actor when `actor` is empty
CLEAR_LONG = 2.0  # m kept free ahead of and behind a placed actor (background agents there are removed)
CLEAR_LAT = 0.3  # m kept free beside it
KERB_GAP = 0.1  # m between a bus at the kerb and the carriageway edge
MAX_SLIP = 0.8  # a scripted vehicle moves sideways at most this share of its forward speed (about 39 degrees)


@dataclasses.dataclass
class _Running:
    """One event's progress: its spec, the uids it placed (actor first), when, and the manoeuvre goal."""

    spec: dict[str, Any]
    uids: list[int] = dataclasses.field(default_factory=list)
    placed_at: float = math.nan
    goal_y: float = math.nan  # m, set when the manoeuvre starts
    done: bool = False  # placement attempted (placed, or skipped because the ego was absent)


class EventScript:
    """The scripted events of one episode; `Traffic.step` asks it for the actors' commands every step.

    events: EventSpec fields as dicts (scenario.to_dict()["events"]); t0: Traffic.time at the end of
    warm-up (event times count from there).
    """

    def __init__(self, events: list[dict[str, Any]], t0: float) -> None:
        self.events = [_Running(dict(e)) for e in events]
        self.t0 = t0

    def scripted_uids(self) -> np.ndarray:
        """(k,) uids of every agent the script drives."""
        return np.array([u for ev in self.events for u in ev.uids], np.int64)

    def commands(self, traffic: Any, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Place due actors, then (acceleration, lateral speed) (n,) m/s^2, m/s per row; nan: not scripted."""
        clock = traffic.time - self.t0
        for ev in self.events:
            if not ev.done and clock >= float(ev.spec["at"]) - float(ev.spec["lead"]) - 1e-9:
                ev.done = True
                if traffic.ego_row >= 0:
                    self._place(traffic, ev, clock)
        s = traffic.state
        acc, vy = np.full(s.n, np.nan), np.full(s.n, np.nan)
        for ev in self.events:  # a handful of events per episode; the arrays inside are whole rows
            rows = np.array([traffic.row_of(u, missing=-1) for u in ev.uids], int)
            rows = rows[rows >= 0]
            if rows.size == 0:
                continue
            acc[rows], vy[rows] = 0.0, 0.0  # hold speed and line (and the bus of step_out stays put)
            actor = traffic.row_of(ev.uids[0], missing=-1)
            if actor < 0 or clock < ev.placed_at + float(ev.spec["lead"]) + float(ev.spec["delay"]) - 1e-9:
                continue
            if not np.isfinite(ev.goal_y):
                ev.goal_y = self._goal(traffic, ev, actor)
            acc[actor], vy[actor] = self._manoeuvre(s, ev, actor, dt)
        return acc, vy

    # ------------------------------------------------------------------ placement
    def _place(self, traffic: Any, ev: _Running, clock: float) -> None:
        s, e, sp = traffic.state, traffic.ego_row, ev.spec
        hw = traffic.half_width
        kind = sp["kind"]
        actor_type = AgentType.parse(sp["actor"] or ACTORS[kind])
        front = s.x[e] + 0.5 * s.length[e] + float(sp["ahead"]) + float(sp["ahead_time"]) * s.vx[e]
        speed = float(s.vx[e]) if sp["speed"] < 0 else float(sp["speed"])
        kerb = 1.0 if sp["side"] > 0 else -1.0
        placed: list[tuple[AgentType, float, float, float]] = []  # (type, x centre, y centre, speed)
        if kind in ("step_out", "pull_out"):
            bus = AgentType.BUS
            bl, bw = float(PARAMS["length"][bus]), float(PARAMS["width"][bus])
            bus_y = kerb * (hw - 0.5 * bw - KERB_GAP)
            if kind == "pull_out":  # the actor (a bus unless `actor` says otherwise) against the kerb
                al, aw = float(PARAMS["length"][actor_type]), float(PARAMS["width"][actor_type])
                placed.append((actor_type, front + 0.5 * al, kerb * (hw - 0.5 * aw - KERB_GAP),
                               speed if sp["speed"] >= 0 else 0.0))
            else:
                pl, pw = float(PARAMS["length"][actor_type]), float(PARAMS["width"][actor_type])
                front = max(front, s.x[e] + 0.5 * s.length[e] + bl + 1.0)  # the bus must fit in front of the ego
                placed.append((actor_type, front + 0.5 * pl, kerb * (hw - 0.5 * pw - KERB_GAP), 0.0))
                placed.append((bus, front - 0.5 - 0.5 * bl, bus_y, 0.0))  # just behind the pedestrian
        else:
            al, aw = float(PARAMS["length"][actor_type]), float(PARAMS["width"][actor_type])
            lim = hw - 0.5 * aw - KERB_GAP
            placed.append((actor_type, front + 0.5 * al, float(np.clip(s.y[e] + sp["side"], -lim, lim)), speed))
        for t, x, y, v in placed:
            x += float(sp["lead"]) * (float(s.vx[e]) - v)  # what the ego, keeping its speed, closes in the lead
            self._clear(traffic, t, x, y)
            cols = traffic._new_columns(int(t), VEHICLE)
            cols["v0"] = max(v, 0.1)
            traffic.state.append(**cols, x=x, y=y, vx=v, vy=0.0, y_target=y)
            ev.uids.append(int(cols["uid"]))
        ev.placed_at = clock

    def _clear(self, traffic: Any, agent_type: AgentType, x: float, y: float) -> None:
        """Remove the background agents (never the ego or scripted actors) that the new actor's box would crowd."""
        s = traffic.state
        hx = 0.5 * float(PARAMS["length"][agent_type]) + CLEAR_LONG
        hy = 0.5 * float(PARAMS["width"][agent_type]) + CLEAR_LAT
        crowd = (np.abs(s.x - x) < hx + 0.5 * s.length) & (np.abs(s.y - y) < hy + 0.5 * s.width)
        crowd &= ~s.is_ego & ~np.isin(s.uid, self.scripted_uids())
        if crowd.any():
            s.keep(~crowd)

    # ------------------------------------------------------------------ the manoeuvre
    def _goal(self, traffic: Any, ev: _Running, actor: int) -> float:
        """Lateral offset (m) the actor heads for, fixed when its manoeuvre starts."""
        s, sp, hw = traffic.state, ev.spec, traffic.half_width
        if sp["kind"] == "step_out":  # crosses the whole carriageway, onto the far sidewalk
            return float(-np.sign(s.y[actor]) * (hw + 0.5))
        e = traffic.ego_row
        ref = s.y[e] if e >= 0 else s.y[actor]
        lim = hw - 0.5 * s.width[actor] - KERB_GAP
        return float(np.clip(ref + sp["target"], -lim, lim))

    @staticmethod
    def _manoeuvre(s: Any, ev: _Running, row: int, dt: float) -> tuple[float, float]:
        """(acceleration m/s^2, lateral speed m/s) of the actor this step."""
        sp = ev.spec
        v = float(s.vx[row])
        a = float(np.clip((float(sp["end_speed"]) - v) / dt, -float(sp["decel"]), float(sp["accel"])))
        lim = float(sp["lateral_speed"])
        if s.agent_type[row] != AgentType.PEDESTRIAN:  # vehicles steer; they do not slide sideways
            lim = min(lim, MAX_SLIP * max(v, 0.0))
        return a, float(np.clip((ev.goal_y - s.y[row]) / dt, -lim, lim))
