"""libsumo backend: dense, heterogeneous, lane-less traffic with pedestrians and a harness-driven ego.

One simulation per process (libsumo's limit): a second live `SumoSimulator` raises `SimulatorError`.
The network is built once per simulator (it depends on the spec only); routes are written per seed
into a private temp folder. The effective SUMO seed is `spec.seed + seed`.

Recorded per agent and frame: centre xy (SUMO reports the front bumper), heading of motion (SUMO's
angle, degrees clockwise from north, follows lateral speed in the sub-lane model), speed, type and
footprint, and extras "sim_heading" (SUMO's lane-aligned box heading, what its own collision check
uses) and "lateral_offset" (m from the carriageway centre line, positive left).

Reading (traffic.py): constants once per vehicle, five getters per vehicle and recorded frame
(cheaper than subscriptions, measured). Recorded and unrecorded stepping run the same
simulation (tests/test_sumo.py); the recorded path hands its read to the crossing pedestrians.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from simharness.errors import SimulatorError
from simharness.scenario import ScenarioSpec
from simharness.scene import DEFAULT_FOOTPRINT, AgentType
from simharness.sim.base import EgoCommand, Event, Frame, RoadGeometry, ego_lateral_limit
from simharness.sim.sumo.demand import KINEMATICS, routes_xml
from simharness.sim.sumo.ego import GhostEgo, ego_start, entry_speed, free_lateral, lateral_move
from simharness.sim.sumo.events import EgoPose, EventScript
from simharness.sim.sumo.net import Network, build_network
from simharness.sim.sumo.pedestrians import Crossings
from simharness.sim.sumo.traffic import Traffic, VehicleTable, read_traffic, rear_of

os.environ.setdefault("LIBSUMO_AS_TRACI", "quiet")  # libsumo prints a pyarrow ABI note to stdout otherwise
import libsumo  # noqa: E402

_LIVE: list[SumoSimulator] = []  # the one simulator allowed to hold libsumo in this process
EGO_ID = "ego"
DEFAULT_LC_MODE = 1621
DEFAULT_SPEED_MODE = 31
# SUMO's default: a minor-road driver at the dense priority crossing may wait 2-5 min for a gap (120 s gave
# 4 teleports per 300 s there, all of waiting vehicles; 300 s gave none on 4 seeds); stuck ones still teleport.
TIME_TO_TELEPORT = 300.0
CUT_IN_AHEAD = (1.0, 12.0)  # m between the ego's front and a passing vehicle's rear when it is told to cut in


class SumoSimulator:
    """`Simulator` over libsumo; see the module doc. Use one per process and close it."""

    def __init__(self, spec: ScenarioSpec) -> None:
        if spec.backend != "sumo":
            raise ValueError(f"SumoSimulator needs a sumo scenario, got backend {spec.backend!r}")
        self.spec = spec
        self.dt = spec.dt
        self._folder = Path(tempfile.mkdtemp(prefix="simharness_sumo_"))
        self.net: Network = build_network(spec.road, self._folder / "net")
        self.road: RoadGeometry = self.net.road
        self._running = False
        self.seed: int | None = None

    # ------------------------------------------------------------------ lifecycle
    def reset(self, seed: int) -> Frame:
        """Start SUMO with seed `spec.seed + seed`, run the warm-up, return the frame at t = 0."""
        self.close()
        if _LIVE:
            raise SimulatorError(
                f"scenario {self.spec.name}, seed {seed}: another SumoSimulator ({_LIVE[0].spec.name}, seed "
                f"{_LIVE[0].seed}) is running in this process; libsumo allows one simulation per process "
                "(close it first, or use one process per simulation)")
        self.seed = int(seed)
        sumo_seed = self.spec.seed + self.seed
        run = self._folder / f"seed{self.seed}"
        run.mkdir(exist_ok=True)
        end = self.spec.warmup + self.spec.duration + 3600.0
        rou = run / "routes.rou.xml"
        rou.write_text(routes_xml(self.spec, self.net, end))
        args = ["sumo", "-n", str(self.net.net_file), "-r", str(rou), "--seed", str(sumo_seed),
                "--step-length", f"{self.spec.step_length}", "--collision.mingap-factor", "0",
                "--collision.action", "warn", "--collision.check-junctions", "true",
                "--time-to-teleport", f"{TIME_TO_TELEPORT:g}", "--no-step-log", "true", "--no-warnings", "true",
                "--duration-log.disable", "true", "--default.action-step-length", f"{self.spec.step_length}",
                "--max-depart-delay", "30", "--threads", "1", "--log", str(run / "sumo.log")]
        for f in (self.net.net_file, rou):  # libsumo crashes the process on malformed XML: check first
            try:
                ElementTree.parse(f)
            except (ElementTree.ParseError, OSError) as e:
                raise SimulatorError(f"scenario {self.spec.name}, seed {seed}: SUMO input {f.name} is not "
                                     f"valid XML: {e}") from None
        if self.spec.sublane.lateral_resolution > 0:
            args += ["--lateral-resolution", f"{self.spec.sublane.lateral_resolution}"]
        try:
            with _stderr_to(run / "sumo.err"):  # SUMO writes load errors to the C stderr, not to its log
                libsumo.start(args)
        except Exception as e:  # libsumo raises its own TraCIException / FatalTraCIError
            raise SimulatorError(f"scenario {self.spec.name}, seed {seed}: SUMO failed to start: "
                                 f"{self._sumo_said(e)}") from None
        _LIVE.append(self)
        self._running = True
        self._table = VehicleTable(Crossings.public_id)
        self._steps = 0  # SUMO steps since start
        self._traffic: Traffic | None = None  # the latest read of every vehicle
        self._contacts: set[tuple[str, str]] = set()
        self._events: list[Event] = []
        self._t = 0.0
        self._ego_controlled = False
        self._ego_in_sumo = False
        self._ego_lat_v = 0.0
        self._cut_in: set[str] = set()
        self._cut_done: set[str] = set()  # vehicles already told to cut in front of the ego
        self._lane_index, self._lane_table = self._read_lanes()
        rng = np.random.default_rng([sumo_seed, 7])
        self._crossings = Crossings(self.spec, self.net, rng)
        self._ghost: GhostEgo | None = None
        self._ego_due = self.spec.ego.enabled
        self._ego_from = self.spec.warmup  # SUMO time (s) from which insert_at counts; restart_ego moves it
        self._script = self._event_script()
        warm_steps = int(round(self.spec.warmup / self.spec.step_length))
        self._advance(warm_steps, recording=False)
        self._events.clear()
        return self._frame()

    def step(self, ego_command: EgoCommand | None = None) -> Frame:
        """Advance one recorded frame (spec.steps_per_frame SUMO steps); the ego follows `ego_command`."""
        self._require_running()
        self._advance(self.spec.steps_per_frame, recording=True, command=ego_command)
        self._t += self.dt
        return self._frame(ego_command, moved=True)

    def advance_unrecorded(self, frames: int) -> None:
        """Step `frames` recorded frames' worth of SUMO steps without reading agents ("raw stepping")."""
        self._require_running()
        for _ in range(frames):
            self._advance(self.spec.steps_per_frame, recording=False)
            self._t += self.dt

    def restart_ego(self) -> Frame:
        """A new ego run in the running traffic: the ego leaves, and enters again at its start point on the
        next step as at reset (SUMO's clock runs on; recorded time restarts at 0). Background vehicles
        keep what they were told for a cut-in ego."""
        self._require_running()
        if not self.spec.ego.enabled:
            raise SimulatorError(f"scenario {self.spec.name}: restart_ego needs the scenario's ego enabled")
        if self._ego_in_sumo and EGO_ID in libsumo.vehicle.getIDList():
            libsumo.vehicle.remove(EGO_ID)
        self._ghost = None
        self._ego_in_sumo = self._ego_controlled = False
        self._ego_lat_v = 0.0
        self._ego_due = True
        self._ego_from = float(libsumo.simulation.getTime())
        self._script = self._event_script()
        self._contacts = {c for c in self._contacts if EGO_ID not in c}
        self._events.clear()
        self._t = 0.0
        return self._frame()

    def close(self) -> None:
        """End the SUMO run (the network folder stays until the object is garbage collected)."""
        if self._running:
            self._running = False
            try:
                libsumo.close()
            except Exception:  # already dead: nothing to release
                pass
            finally:
                if self in _LIVE:
                    _LIVE.remove(self)

    def __del__(self) -> None:
        try:
            self.close()
            shutil.rmtree(self._folder, ignore_errors=True)
        except Exception:  # interpreter shutdown: modules may be gone
            pass

    def __enter__(self) -> SumoSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ scripted events
    def _event_script(self) -> EventScript | None:
        """The scenario's events, timed from the ego's start (a restarted ego gets them afresh)."""
        old = getattr(self, "_script", None)
        if old is not None:  # a restart: the last run's actors leave
            for a in old.actors():
                if a.vid in libsumo.vehicle.getIDList():
                    libsumo.vehicle.remove(a.vid)
        if not self.spec.events:
            return None
        cw, _ = ego_start(self.net)
        two_way = self.spec.road.layout == "intersection" or self.spec.road.bidirectional
        route = f"r_{cw.edge}" if f"r_{cw.edge}" in self.net.routes else \
            next(r for r, e in self.net.routes.items() if e[0] == cw.edge)
        return EventScript([dataclasses.asdict(e) for e in self.spec.events], cw, cw.width * (1.5 if two_way else 0.5),
                           route, self._ego_from)

    def _ego_pose(self) -> EgoPose | None:
        """The ego now in the events' frame (front s, centre lat, length, speed), or None if it is absent."""
        if self._script is None:
            return None
        if self._ghost is not None:
            g = self._ghost.state()
            centre, length, speed = np.asarray(g["xy"], float), float(g["length"]), float(self._ghost.v)
        elif self._ego_in_sumo and EGO_ID in libsumo.vehicle.getIDList():
            front = np.array(libsumo.vehicle.getPosition(EGO_ID), float)
            a = math.radians(libsumo.vehicle.getAngle(EGO_ID))
            length, speed = float(libsumo.vehicle.getLength(EGO_ID)), float(libsumo.vehicle.getSpeed(EGO_ID))
            centre = front - 0.5 * length * np.array([math.sin(a), math.cos(a)])
        else:
            return None
        s, lat = self._script.from_world(centre[None])
        return float(s[0]) + 0.5 * length, float(lat[0]), length, speed

    # ------------------------------------------------------------------ stepping
    def _require_running(self) -> None:
        if not self._running:
            raise SimulatorError(f"scenario {self.spec.name}: SumoSimulator is not running (call reset first)")

    def _sumo_said(self, e: BaseException) -> str:
        text = str(e).strip()
        err = self._folder / f"seed{self.seed}" / "sumo.err"
        if err.exists():
            lines = [ln for ln in err.read_text(errors="replace").splitlines() if ln.strip()]
            if lines:
                text = lines[-1].strip()
        return text or type(e).__name__

    def _advance(self, steps: int, recording: bool, command: EgoCommand | None = None) -> None:
        """SUMO steps with per-step bookkeeping (ego, crossing pedestrians, collisions, teleports).

        Recorded and unrecorded stepping do the same simulation work: at the start of every frame the
        crossing pedestrians (and a cut-in ego's neighbours) decide on one read of every vehicle, which
        the recorded path takes from the frame it has just recorded and the unrecorded path reads.
        """
        sl, per_frame = self.spec.step_length, self.spec.steps_per_frame
        for k in range(steps):
            frame_start = k % per_frame == 0
            if self.spec.ego.enabled and (recording or self._ego_due):
                self._control_ego(command, sl, frame_start)
            self._crossings.step(libsumo, sl, frame_start, self._traffic_now)
            if self._script is not None:
                self._script.step(libsumo, libsumo.simulation.getTime(), sl, self._ego_pose)
            try:
                libsumo.simulationStep()
            except Exception as e:
                self.close()
                raise SimulatorError(f"scenario {self.spec.name}, seed {self.seed}: SUMO died at "
                                     f"t={libsumo_time_safe():.1f} s: {self._sumo_said(e)}") from None
            self._steps += 1
            self._collect_events(self._t + (k + 1) * sl)
        if not recording:
            self._crossings.mark()

    def _traffic_now(self) -> Traffic:
        """Every vehicle at the current step: the frame's own read when it is current, else a fresh read."""
        if self._traffic is None or self._traffic.step != self._steps:
            self._traffic = read_traffic(libsumo, self._table, self._steps)
        return self._traffic

    def _collect_events(self, t: float) -> None:
        """Collisions (first step of each contact only) and teleports of the last SUMO step."""
        now = set()
        for c in libsumo.simulation.getCollisions():
            pair = (c.collider, c.victim)
            now.add(pair)
            if pair not in self._contacts:
                self._events.append(Event("collision", round(t, 6), Crossings.public_id(c.collider),
                                          Crossings.public_id(c.victim),
                                          f"{c.type} {c.colliderType}/{c.victimType} lane {c.lane}"))
        self._contacts = now
        for vid in libsumo.simulation.getStartingTeleportIDList():
            self._events.append(Event("teleport", round(t, 6), Crossings.public_id(vid)))

    # ------------------------------------------------------------------ ego
    def _control_ego(self, command: EgoCommand | None, sl: float, frame_start: bool) -> None:
        spec = self.spec.ego
        now = libsumo.simulation.getTime()
        if self._ego_due and now >= self._ego_from + spec.insert_at - 1e-9:
            self._ego_due = False
            self._insert_ego()
        if self._ghost is not None:
            return  # the ghost moves once per frame in _frame()
        if not self._ego_in_sumo or EGO_ID not in libsumo.vehicle.getIDList():
            return
        if command is None:
            if self._ego_controlled:  # hand the ego back to SUMO's own models
                libsumo.vehicle.setSpeed(EGO_ID, -1)
                libsumo.vehicle.setSpeedMode(EGO_ID, DEFAULT_SPEED_MODE)
                libsumo.vehicle.setLaneChangeMode(EGO_ID, DEFAULT_LC_MODE)
                self._ego_controlled = False
        else:
            if not self._ego_controlled:
                libsumo.vehicle.setSpeedMode(EGO_ID, 0)  # the harness alone decides (it may collide)
                libsumo.vehicle.setLaneChangeMode(EGO_ID, 0)
                self._ego_controlled = True
            t = AgentType.parse(spec.type)
            _, _, vmax, accel, decel, _, vlat, _ = KINEMATICS[t]
            a = float(np.clip(command.acceleration, -2.0 * decel, accel))
            v_was = libsumo.vehicle.getSpeed(EGO_ID)
            v = float(np.clip(v_was + a * sl, 0.0, vmax))
            libsumo.vehicle.setSpeed(EGO_ID, v)
            lim = float(ego_lateral_limit(vlat, v_was, v))
            self._ego_lat_v = 0.0
            if command.lateral_velocity != 0.0 and lim > 0.0:
                lane = libsumo.vehicle.getLaneID(EGO_ID)
                half = libsumo.lane.getWidth(lane) / 2 - libsumo.vehicle.getWidth(EGO_ID) / 2
                was = libsumo.vehicle.getLateralLanePosition(EGO_ID)
                lat = lateral_move(command.lateral_velocity, was, half, lim, sl)
                libsumo.vehicle.setLateralLanePosition(EGO_ID, lat)
                self._ego_lat_v = (lat - was) / sl  # what it moved: at the lane's edge, less than commanded
        if self.spec.ego.reaction == "cut_in" and frame_start:
            self._update_cut_in()

    def _insert_ego(self) -> None:
        """Put the ego into running traffic at a free lateral spot on the first entry carriageway."""
        t = AgentType.parse(self.spec.ego.type)
        cw, pos = ego_start(self.net)
        if self.spec.ego.reaction == "ignore":  # invisible to SUMO, so every background agent ignores it
            self._ghost = GhostEgo(self.spec, cw, pos, t)
            return
        # Enter now at the freest lateral spot (a plain insertion may wait seconds for a safe gap), at a speed from
        # which it can stop behind whoever is ahead there.
        now = self._traffic_now()
        length, ego_w = DEFAULT_FOOTPRINT[t]
        lat = free_lateral(cw, pos, now.front, now.width, ego_w)
        speed = entry_speed(cw, pos, lat, (now.front + now.rear) / 2, now.length, now.width, now.speed, length, ego_w,
                            self.spec.ego.speed, self.spec.dt)
        libsumo.vehicle.add(EGO_ID, f"r_{cw.edge}" if f"r_{cw.edge}" in self.net.routes else
                            next(r for r, e in self.net.routes.items() if e[0] == cw.edge),
                            typeID=f"{self.spec.ego.type}__ego", depart="now", departLane="0",
                            departPos=f"{pos:.2f}", departSpeed=f"{speed:.2f}")
        front = cw.start + cw.direction * (pos + length / 2) + cw.right * (cw.centre_offset - lat)
        angle = math.degrees(math.atan2(cw.direction[0], cw.direction[1])) % 360.0
        libsumo.vehicle.moveToXY(EGO_ID, cw.edge, -1, float(front[0]), float(front[1]), angle, 2)
        libsumo.vehicle.setColor(EGO_ID, (255, 0, 0, 255))
        self._ego_lat_v = 0.0
        self._ego_in_sumo = True

    def _update_cut_in(self) -> None:
        """Background vehicles near the ego stop yielding laterally, and those just passing it cut in.

        Within 50 m: no cooperation, pushy and assertive lane changing. A vehicle whose rear has just
        cleared the ego's front (CUT_IN_AHEAD m), beside its band and not slower, is told once to move
        sideways onto the ego's line (`changeSublane`: SUMO still keeps it from hitting anyone).
        """
        t = self._traffic_now()
        if EGO_ID not in t.ids:
            return
        e = t.ids.index(EGO_ID)
        vehicle = self._table.agent_type[t.rows] != AgentType.PEDESTRIAN
        vehicle[e] = False
        rel = t.front - t.front[e]
        near = {t.ids[i] for i in np.flatnonzero(vehicle & (np.sum(rel ** 2, axis=1) < 2500.0))}
        for vid in sorted(near - self._cut_in):
            libsumo.vehicle.setParameter(vid, "laneChangeModel.lcCooperative", "0")
            libsumo.vehicle.setParameter(vid, "laneChangeModel.lcPushy", "1")
            libsumo.vehicle.setParameter(vid, "laneChangeModel.lcAssertive", "5")
        self._cut_in = near | (self._cut_in & set(t.ids))
        axis = t.front[e] - t.rear[e]
        axis /= max(float(np.linalg.norm(axis)), 1e-9)
        along, left = rel @ axis, rel @ np.array([-axis[1], axis[0]])  # (n,) m, from the ego's front bumper
        rear_gap = along - t.length
        beside = np.abs(left) > (t.width + t.width[e]) / 2
        cut = vehicle & beside & (np.abs(left) < 4.0) & (rear_gap > CUT_IN_AHEAD[0]) & (rear_gap < CUT_IN_AHEAD[1])
        cut &= t.speed >= t.speed[e] - 0.5
        for i in np.flatnonzero(cut):  # asked every frame until it is in the ego's band
            self._cut_done.add(t.ids[i])
            libsumo.vehicle.changeSublane(t.ids[i], float(-left[i]))

    # ------------------------------------------------------------------ reading
    def _read_lanes(self) -> tuple[dict[str, int], np.ndarray]:
        """Lane id -> row of a (lanes + 1, 2) table: its centre's offset from the carriageway centre (m, + left)
        and its direction (rad CCW from +x); the last row (0, nan) stands for "no lane"."""
        index, rows = {}, []
        for lane in libsumo.lane.getIDList():
            shape = np.asarray(libsumo.lane.getShape(lane))
            d = shape[-1] - shape[0]
            edge = libsumo.lane.getEdgeID(lane)
            if lane.startswith(":"):
                offset = 0.0
            else:
                n = libsumo.edge.getLaneNumber(edge)
                idx = int(lane.rsplit("_", 1)[1])
                offset = (idx - (n - 1) / 2) * libsumo.lane.getWidth(lane)
            index[lane] = len(rows)
            rows.append((offset, math.atan2(d[1], d[0])))
        rows.append((0.0, np.nan))
        return index, np.array(rows, np.float64)

    def _frame(self, command: EgoCommand | None = None, moved: bool = False) -> Frame:
        """Every agent now: getters for what moves, constants from the table traffic.py says why)."""
        g = libsumo.vehicle
        ids = g.getIDList()
        n = len(ids)
        rows = self._table.rows(libsumo, ids)
        front = np.array([g.getPosition(v) for v in ids], dtype=np.float64).reshape(n, 2)
        angle = np.fromiter((g.getAngle(v) for v in ids), np.float64, n)
        speed = np.fromiter((g.getSpeed(v) for v in ids), np.float64, n)
        lane_of = self._lane_index.get
        lane = np.fromiter((lane_of(g.getLaneID(v), -1) for v in ids), np.int64, n)
        lat = np.fromiter((g.getLateralLanePosition(v) for v in ids), np.float64, n)
        length, width, agent_type = self._table.length[rows], self._table.width[rows], self._table.agent_type[rows]
        # The next step's gap decisions use this read (the unrecorded path reads the same itself).
        self._traffic = Traffic(self._steps, ids, rows, front, speed, length, width, rear_of(front, angle, length))
        info = self._lane_table[lane]
        heading = np.mod(np.radians(90.0 - angle) + math.pi, 2 * math.pi) - math.pi
        sim_heading = np.where(np.isnan(info[:, 1]), heading, info[:, 1])
        # Centre of SUMO's own (lane-aligned) box, so boxes at sim_heading reproduce its collision geometry.
        xy = front - np.stack([np.cos(sim_heading), np.sin(sim_heading)], -1) * (length[:, None] / 2)
        lateral = info[:, 0] + lat
        agent_id = self._table.public[rows]
        speed = speed.copy()  # the Traffic read keeps SUMO's own speeds
        self._crossings.override_motion(ids, heading, speed, self.dt)
        if self._script is not None:
            self._script.override(ids, xy, heading, sim_heading, speed, lateral)
        ego = -1
        if self._ghost is not None:
            if moved:
                self._ghost.advance(command, self.dt, xy, heading, speed, length, width, agent_id)
                self._events += [Event("collision", round(self._t, 6), EGO_ID, other, "ghost ego overlap")
                                 for other in self._ghost.new_contacts]
            gx = self._ghost.state()
            agent_id = np.append(agent_id, EGO_ID)
            xy = np.vstack([xy, gx["xy"][None]])
            heading, sim_heading = np.append(heading, gx["heading"]), np.append(sim_heading, gx["sim_heading"])
            speed, lateral = np.append(speed, gx["speed"]), np.append(lateral, gx["lateral"])
            agent_type = np.append(agent_type, np.int8(gx["type"]))
            length, width = np.append(length, gx["length"]), np.append(width, gx["width"])
            ego = n
        elif EGO_ID in ids:
            ego = ids.index(EGO_ID)
            if self._ego_controlled:  # SUMO reports a lane-aligned angle for a harness-moved ego
                heading[ego] = sim_heading[ego] + math.atan2(self._ego_lat_v, max(float(speed[ego]), 1e-3))
                speed[ego] = math.hypot(float(speed[ego]), self._ego_lat_v)
        return Frame(
            t=round(self._t, 6), agent_id=agent_id.astype(str), agent_type=agent_type.astype(np.int8),
            xy=xy.astype(np.float32), heading=heading.astype(np.float32), speed=speed.astype(np.float32),
            length=length.astype(np.float32), width=width.astype(np.float32), ego=ego,
            extra={"sim_heading": sim_heading.astype(np.float32), "lateral_offset": lateral.astype(np.float32)},
            events=tuple(self._drain_events()),
        )

    def _drain_events(self) -> list[Event]:
        out, self._events = self._events, []
        return out


@contextlib.contextmanager
def _stderr_to(path: Path) -> Iterator[None]:
    """Redirect the process's file descriptor 2 (C-level stderr) into `path` for the block."""
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "ab") as f:
        os.dup2(f.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def libsumo_time_safe() -> float:
    try:
        return float(libsumo.simulation.getTime())
    except Exception:
        return float("nan")
