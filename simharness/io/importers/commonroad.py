"""CommonRoad XML scenarios (NGSIM via CommonRoad, with the lanelets as drivable area) -> Scenes; parsed with
entity expansion and external entities refused."""

from __future__ import annotations

import xml.etree.ElementTree as ET
import xml.parsers.expat as pyexpat
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.io.importers.source import (
    PathLike,
    check_file,
    integral,
    scene_from_rows,
    source_meta,
    where_lines,
)
from simharness.scene import AgentType, Scene

COMMONROAD_TYPES = {
    "car": AgentType.CAR, "taxi": AgentType.CAR, "priorityVehicle": AgentType.CAR, "parkedVehicle": AgentType.CAR,
    "truck": AgentType.TRUCK, "bus": AgentType.BUS, "motorcycle": AgentType.MOTORCYCLE,
    "bicycle": AgentType.BICYCLE, "pedestrian": AgentType.PEDESTRIAN,
}


def _parse_xml(path: Path) -> tuple[ET.Element, dict[int, int]]:
    """Element tree plus each element's source line (keyed by id(element)), for error messages."""
    expat = pyexpat.ParserCreate()
    builder = ET.TreeBuilder()
    lines: dict[int, int] = {}

    def start(tag: str, attrs: dict[str, str]) -> None:
        lines[id(builder.start(tag, attrs))] = expat.CurrentLineNumber

    expat.StartElementHandler = start
    expat.EndElementHandler = builder.end
    expat.CharacterDataHandler = builder.data
    try:
        expat.Parse(path.read_bytes(), True)
    except pyexpat.ExpatError as e:
        raise UserError(f"{path}:{e.lineno}: not well-formed XML ({pyexpat.ErrorString(e.code)})") from None
    return builder.close(), lines


def _cr_value(elem: ET.Element, tag: str, path: Path, lines: dict[int, int]) -> float:
    """`<tag><exact>v</exact></tag>` or an interval's midpoint; UserError naming the line if missing."""
    node = elem.find(tag)
    if node is None:
        raise UserError(f"{path}:{lines.get(id(elem), 0)}: <{elem.tag}> lacks <{tag}>")
    exact = node.findtext("exact")
    try:
        if exact is not None:
            return float(exact)
        return (float(node.findtext("intervalStart")) + float(node.findtext("intervalEnd"))) / 2
    except (TypeError, ValueError):
        raise UserError(f"{path}:{lines.get(id(node), 0)}: <{tag}> needs a number in <exact> "
                        f"or <intervalStart>/<intervalEnd>") from None


def _cr_point(state: ET.Element, path: Path, lines: dict[int, int]) -> tuple[float, float]:
    pt = state.find("position/point")
    if pt is None:
        raise UserError(f"{path}:{lines.get(id(state), 0)}: <{state.tag}> lacks <position><point>")
    try:
        return float(pt.findtext("x")), float(pt.findtext("y"))
    except (TypeError, ValueError):
        raise UserError(f"{path}:{lines.get(id(pt), 0)}: <point> needs numeric <x> and <y>") from None


def _cr_road(root: ET.Element) -> dict[str, Any]:
    """Lanelets as a `RoadGeometry` dict: each lanelet a drivable polygon, its bounds as markings."""
    drivable, markings = [], []
    for lanelet in root.iter("lanelet"):
        bounds = []
        for side in ("leftBound", "rightBound"):
            pts = [(float(p.findtext("x")), float(p.findtext("y"))) for p in lanelet.findall(f"{side}/point")]
            bounds.append(np.round(np.asarray(pts, np.float64).reshape(-1, 2), 3))
        if len(bounds[0]) >= 2 and len(bounds[1]) >= 2:
            drivable.append(np.concatenate([bounds[0], bounds[1][::-1]]).tolist())
            markings.extend(b.tolist() for b in bounds)
    return {"drivable": drivable, "sidewalks": [], "markings": markings}


def import_commonroad(paths: Sequence[PathLike]) -> list[Scene]:
    """CommonRoad XML scenarios (e.g. the NGSIM US-101 ones), one scene per file, metres.

    Each `dynamicObstacle` is an agent: its `shape/rectangle` gives length and width (a circle gives
    its diameter), `initialState` and `trajectory/state` give position, orientation, velocity at
    integer time steps of `timeStepSize` seconds. The lanelets become the scene's road geometry
    (`meta["road"]`); the planning problem's initial state is kept in `meta["planning_problem"]`.
    """
    scenes = []
    for p in paths:
        path = check_file(p)
        root, lines = _parse_xml(path)
        if root.tag != "commonRoad":
            raise UserError(f"{path}:1: root element is <{root.tag}>; expected <commonRoad>")
        try:
            dt = float(root.get("timeStepSize", ""))
        except ValueError:
            raise UserError(f"{path}:1: <commonRoad> needs a numeric timeStepSize attribute") from None
        frame, agent, xy, head, speed, size, kinds, where = [], [], [], [], [], [], [], []
        unknown: dict[str, int] = {}
        for obs in root.iter("dynamicObstacle"):
            oid = obs.get("id")
            line = lines.get(id(obs), 0)
            if oid is None:
                raise UserError(f"{path}:{line}: <dynamicObstacle> lacks its id attribute")
            kind = (obs.findtext("type") or "").strip()
            if kind not in COMMONROAD_TYPES:
                unknown[kind] = unknown.get(kind, 0) + 1
            rect = obs.find("shape/rectangle")
            circle = obs.find("shape/circle")
            try:
                if rect is not None:
                    dims = (float(rect.findtext("length")), float(rect.findtext("width")))
                elif circle is not None:
                    dims = (2 * float(circle.findtext("radius")),) * 2
                else:
                    dims = AgentType.OTHER.footprint if kind not in COMMONROAD_TYPES else \
                        COMMONROAD_TYPES[kind].footprint
            except (TypeError, ValueError):
                raise UserError(f"{path}:{line}: obstacle {oid}: <shape> needs numeric length/width or radius") \
                    from None
            init = obs.find("initialState")
            if init is None:
                raise UserError(f"{path}:{line}: obstacle {oid} lacks <initialState>")
            for state in [init, *obs.findall("trajectory/state")]:
                frame.append(_cr_value(state, "time", path, lines))
                xy.append(_cr_point(state, path, lines))
                head.append(_cr_value(state, "orientation", path, lines))
                speed.append(_cr_value(state, "velocity", path, lines))
                agent.append(oid)
                size.append(dims)
                kinds.append(COMMONROAD_TYPES.get(kind, AgentType.OTHER))
                where.append(lines.get(id(state), 0))
        where_arr = np.asarray(where)
        frame_arr = integral(np.asarray(frame), where_lines(path, where_arr), "<time>")
        planning = root.find("planningProblem/initialState")
        meta = source_meta(path, "commonroad", path.stem, units="m", benchmark_id=root.get("benchmarkID", ""),
                            commonroad_version=root.get("commonRoadVersion", ""), road=_cr_road(root),
                            unknown_classes=unknown, static_obstacles=len(root.findall("staticObstacle")))
        if planning is not None:
            meta["planning_problem"] = {"xy": list(_cr_point(planning, path, lines)),
                                        "velocity": _cr_value(planning, "velocity", path, lines),
                                        "orientation": _cr_value(planning, "orientation", path, lines)}
        scenes.append(scene_from_rows(
            frame_arr, np.asarray(agent), np.asarray(xy, np.float64).reshape(-1, 2), dt=dt,
            agent_type=np.asarray(kinds, np.int8), heading=np.asarray(head), speed=np.asarray(speed),
            size=np.asarray(size, np.float64).reshape(-1, 2), where=where_lines(path, where_arr), meta=meta,
        ))
    return scenes
