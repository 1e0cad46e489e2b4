"""SUMO road networks from a `RoadSpec`: plain XML nodes/edges through netconvert, plus `RoadGeometry`.

Layouts (world frame, metres, right-hand traffic):
- "arterial": edge "main" from (0, 0) to (length, 0); one direction is centred on y = 0,
  with `bidirectional` the two carriageways ("main" eastbound, "back" westbound) meet at y = 0.
- "intersection": four arms of `length` meeting at (0, 0); edges "<arm>_in" / "<arm>_out" for
  arms w, e, s, n, each direction one carriageway of `width`; the w-e road has priority over
  the s-n road (an unsignalised crossing of a main and a minor road).
Every edge is straight, so positions along it are plain projections (used for pedestrian gaps).
"""

from __future__ import annotations

import dataclasses
import functools
import subprocess
from pathlib import Path

import numpy as np

from simharness.errors import SimulatorError
from simharness.scenario import RoadSpec
from simharness.sim.base import RoadGeometry

ARMS: dict[str, tuple[float, float]] = {"w": (-1.0, 0.0), "e": (1.0, 0.0), "s": (0.0, -1.0), "n": (0.0, 1.0)}


@dataclasses.dataclass(frozen=True)
class Carriageway:
    """One driving direction of a straight edge: where vehicles enter and what they may reach.

    edge: SUMO edge id; start, end: (2,) centre-line end points of the node line (m);
    right: (2,) unit vector to the right of travel; width: carriageway width (m);
    centre_offset: distance from the node line to the carriageway centre, towards `right` (m).
    """

    edge: str
    start: np.ndarray
    end: np.ndarray
    width: float
    centre_offset: float

    @functools.cached_property  # gap checks and crossers use it every step: compute once
    def direction(self) -> np.ndarray:
        d = self.end - self.start
        return d / np.linalg.norm(d)

    @functools.cached_property
    def right(self) -> np.ndarray:
        d = self.direction
        return np.array([d[1], -d[0]])

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    def polygon(self, inset: float = 0.0) -> np.ndarray:
        """(4, 2) corners of the carriageway (shortened by `inset` at both ends)."""
        d, r = self.direction, self.right
        a, b = self.start + d * inset, self.end - d * inset
        near, far = self.centre_offset - self.width / 2, self.centre_offset + self.width / 2
        return np.stack([a + r * near, b + r * near, b + r * far, a + r * far])


@dataclasses.dataclass(frozen=True)
class Network:
    """A built network: the .net.xml path, its entry carriageways and OD routes, and its geometry."""

    net_file: Path
    entries: tuple[Carriageway, ...]  # where flows start (pedestrian crossings use them too)
    routes: dict[str, tuple[str, ...]]  # route id -> edge ids
    entry_routes: dict[str, tuple[tuple[str, float], ...]]  # entry edge -> ((route id, share), ...)
    road: RoadGeometry


def _lanes_xml(width: float, lanes: int) -> str:
    w = width / lanes
    return "".join(f'<lane index="{i}" width="{w:.3f}"/>' for i in range(lanes))


def build_network(road: RoadSpec, folder: Path) -> Network:
    """Write nodes/edges XML into `folder`, run netconvert, and describe the result."""
    folder.mkdir(parents=True, exist_ok=True)
    if road.layout == "arterial":
        nodes = {"W": (0.0, 0.0), "E": (road.length, 0.0)}
        spread = "right" if road.bidirectional else "center"
        edges = [("main", "W", "E")] + ([("back", "E", "W")] if road.bidirectional else [])
        off = road.width / 2 if road.bidirectional else 0.0
        entries = tuple(Carriageway(e, np.array(nodes[a]), np.array(nodes[b]), road.width, off)
                        for e, a, b in edges)
        routes = {f"r_{e}": (e,) for e, _, _ in edges}
        entry_routes = {e: ((f"r_{e}", 1.0),) for e, _, _ in edges}
    elif road.layout == "intersection":
        spread = "right"
        nodes = {"C": (0.0, 0.0)} | {k.upper(): (v[0] * road.length, v[1] * road.length) for k, v in ARMS.items()}
        edges = []
        for k in ARMS:
            edges += [(f"{k}_in", k.upper(), "C"), (f"{k}_out", "C", k.upper())]
        entries = tuple(Carriageway(f"{k}_in", np.array(nodes[k.upper()]), np.zeros(2), road.width, road.width / 2)
                        for k in ARMS)
        # Turning shares: straight on most, left and right the rest (no U-turns).
        opposite = {"w": "e", "e": "w", "s": "n", "n": "s"}
        left_of = {"w": "n", "n": "e", "e": "s", "s": "w"}  # arriving from w (heading east), left is north
        right_of = {"w": "s", "s": "e", "e": "n", "n": "w"}
        routes, entry_routes = {}, {}
        for k in ARMS:
            shares = ((opposite[k], 0.6), (left_of[k], 0.2), (right_of[k], 0.2))
            entry_routes[f"{k}_in"] = tuple((f"r_{k}{o}", s) for o, s in shares)
            for o, _ in shares:
                routes[f"r_{k}{o}"] = (f"{k}_in", f"{o}_out")
    else:  # pragma: no cover - the scenario loader only allows the two layouts
        raise ValueError(road.layout)

    (folder / "net.nod.xml").write_text(
        "<nodes>\n" + "".join(
            f'  <node id="{n}" x="{x:.3f}" y="{y:.3f}" type="{"priority" if n == "C" else "dead_end"}"/>\n'
            for n, (x, y) in nodes.items()) + "</nodes>\n")
    (folder / "net.edg.xml").write_text(
        "<edges>\n" + "".join(
            f'  <edge id="{e}" from="{a}" to="{b}" numLanes="{road.lanes}" speed="{road.speed_limit:.3f}" '
            f'priority="{2 if e[0] in "mbwe" else 1}" '
            f'spreadType="{spread}">{_lanes_xml(road.width, road.lanes)}</edge>\n'
            for e, a, b in edges) + "</edges>\n")
    net_file = folder / "net.net.xml"
    from sumo import SUMO_HOME  # the eclipse-sumo wheel

    cmd = [str(Path(SUMO_HOME) / "bin" / "netconvert"), "--node-files", str(folder / "net.nod.xml"),
           "--edge-files", str(folder / "net.edg.xml"), "--output-file", str(net_file),
           "--offset.disable-normalization", "true", "--no-turnarounds", "true",
           "--junctions.corner-detail", "5", "--no-warnings", "true", "--seed", "0"]
    if road.layout == "intersection":
        cmd += ["--connection-files", str(_connections_xml(routes, folder / "net.con.xml"))]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0 or not net_file.exists():
        msg = (res.stderr or res.stdout).strip().splitlines()
        raise SimulatorError(f"netconvert failed for road {road}: {msg[-1] if msg else res.returncode}")
    return Network(net_file, entries, routes, entry_routes, road_geometry(road, entries))


def _connections_xml(routes: dict[str, tuple[str, ...]], path: Path) -> Path:
    """One connection per route of the intersection; left turns wait at the stop line (contPos 0).

    Why: by default a left-turner waits for a gap inside the junction at a point computed for the lane
    centre; in a 7 m lane-less lane it stands up to 2.6 m off that centre, in the path of oncoming
    traffic, which SUMO's junction model does not see there (8-9 junction collisions per 300 s, 0-2 with contPos 0).
    """
    lines = ["<connections>"]
    for a, b in routes.values():
        wait = ' contPos="0"' if {"w": "n", "n": "e", "e": "s", "s": "w"}[a[0]] == b[0] else ""  # a left turn
        lines.append(f'  <connection from="{a}" to="{b}" fromLane="0" toLane="0"{wait}/>')
    path.write_text("\n".join([*lines, "</connections>"]) + "\n")
    return path


def road_geometry(road: RoadSpec, entries: tuple[Carriageway, ...]) -> RoadGeometry:
    """Drivable carriageways, sidewalks beside them and edge / centre / lane markings, world frame."""
    w, sw = road.width, road.sidewalk_width
    if road.layout == "arterial":
        half = w if road.bidirectional else w / 2  # carriageway(s) span y in [-half, half]
        strips = [(-half, half)]
        axes = [(np.zeros(2), np.array([road.length, 0.0]), 0.0)]
    else:
        half = w  # each arm holds both directions: offsets [-w, w] from its axis
        strips = [(-half, half)]
        axes = [(np.array(u) * w, np.array(u) * road.length, 0.0) for u in ARMS.values()]
    drivable, sidewalks, markings = [], [], []
    for a, b, _ in axes:
        d = (b - a) / np.linalg.norm(b - a)
        n = np.array([-d[1], d[0]])  # left normal

        def strip(lo: float, hi: float, a: np.ndarray = a, b: np.ndarray = b, n: np.ndarray = n) -> np.ndarray:
            return np.stack([a + n * lo, b + n * lo, b + n * hi, a + n * hi])

        for lo, hi in strips:
            drivable.append(strip(lo, hi))
            markings += [np.stack([a + n * lo, b + n * lo]), np.stack([a + n * hi, b + n * hi])]
        if sw > 0:
            sidewalks += [strip(half, half + sw), strip(-half - sw, -half)]
        if road.layout == "intersection" or road.bidirectional:
            markings.append(np.stack([a, b]))  # centre line between the two directions
        for cw in entries:  # lane lines inside marked carriageways
            if road.layout == "arterial":
                r = cw.right
                for i in range(1, road.lanes):
                    o = cw.centre_offset - cw.width / 2 + i * cw.width / road.lanes
                    markings.append(np.stack([cw.start + r * o, cw.end + r * o]))
    if road.layout == "intersection":
        drivable.append(np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float) * w)
    return RoadGeometry(tuple(drivable), tuple(sidewalks), tuple(markings))
