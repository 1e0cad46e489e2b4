"""`simharness stats DIR`: a data set's figures in the form of the TraPHic paper's Table 1.

Frames, average agents per frame (overall and by type), distinct types, neighbours within 50 m,
density (agents per km of road), speed and lateral-offset spread by type, collisions (as the
simulator reported them AND as oriented-box overlaps computed from the data, labelled) and
teleports. Everything is computed per scene with array code, then summed.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from simharness.errors import UserError
from simharness.io.parquet import Dataset
from simharness.metrics.collisions import box_heading, collision_events
from simharness.scene import AgentType, Scene
from simharness.sim.base import RoadGeometry

NEIGHBOUR_RADIUS_M = 50.0
NUM_TYPES = len(AgentType)
PED = int(AgentType.PEDESTRIAN)
FIGURE_WINDOW_M = 120.0  # stretch of a long road drawn in the frame figure


# ---------------------------------------------------------------------- pure per-scene figures
def neighbours_within(xy: np.ndarray, valid: np.ndarray, radius: float = NEIGHBOUR_RADIUS_M) -> np.ndarray:
    """Other valid agents within `radius` of each agent, same frame.

    xy (N, T, 2) metres, valid (N, T) -> (N, T) int (0 where invalid).
    """
    rows, cols = np.nonzero(valid)
    out = np.zeros(valid.shape, np.int64)
    if rows.size == 0:
        return out
    # Frames as a third coordinate far apart, so one tree answers every frame at once.
    span = float(np.ptp(xy[rows, cols], axis=0).max()) + 2 * radius + 1.0
    pts = np.column_stack([xy[rows, cols].astype(np.float64), cols * span])
    out[rows, cols] = cKDTree(pts).query_ball_point(pts, radius, return_length=True) - 1
    return out


def types_per_frame(agent_type: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Agents of each type present at each frame: agent_type (N,), valid (N, T) -> (NUM_TYPES, T) int."""
    onehot = np.eye(NUM_TYPES, dtype=np.int64)[agent_type.astype(np.int64)]  # (N, NUM_TYPES)
    return onehot.T @ valid.astype(np.int64)


def lateral_values(scene: Scene) -> tuple[np.ndarray, str]:
    """(N, T) lateral position used for the spread: `extra["lateral_offset"]` if recorded, else y."""
    if "lateral_offset" in scene.extra:
        return scene.extra["lateral_offset"], "lateral_offset"
    return scene.xy[..., 1], "y"


def road_length_m(road: RoadGeometry | None, spec: dict[str, Any] | None) -> float | None:
    """Length of road the agents share, metres.

    From the scenario spec when the data set was generated (arterial length; four arms of an
    intersection), else from the drivable polygons (each taken as a rectangle: sum of long sides).
    """
    length = spec.get("road", {}).get("length") if isinstance(spec, dict) and isinstance(spec.get("road"), dict) \
        else None
    if isinstance(length, (int, float)) and not isinstance(length, bool) and np.isfinite(length) and length > 0:
        arms = 4 if spec["road"].get("layout") == "intersection" else 1
        return float(length) * arms
    if road is None or not road.drivable:
        return None
    total = 0.0
    for poly in road.drivable:
        p = np.asarray(poly, np.float64)
        x, y = p[:, 0], p[:, 1]
        area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
        half_perimeter = 0.5 * np.linalg.norm(np.diff(np.vstack([p, p[:1]]), axis=0), axis=1).sum()
        # rectangle with sides L >= W: L + W = half perimeter, L * W = area
        total += 0.5 * (half_perimeter + np.sqrt(max(half_perimeter**2 - 4 * area, 0.0)))
    return total


def pair_kind(type_a: np.ndarray, type_b: np.ndarray) -> np.ndarray:
    """(E,) type codes of two agents -> (E,) labels vehicle-vehicle / vehicle-pedestrian / pedestrian-pedestrian."""
    peds = (type_a == PED).astype(int) + (type_b == PED).astype(int)
    return np.array(["vehicle-vehicle", "vehicle-pedestrian", "pedestrian-pedestrian"])[peds]


# ---------------------------------------------------------------------- data set figures
def dataset_name(info: dict[str, Any], path: Path) -> str:
    """A short name for the table: the scenario, else the imported format, else the folder's name."""
    name = info.get("scenario")
    if isinstance(name, dict):  # closed-loop episodes record the whole spec
        name = name.get("name")
    source = info.get("source")
    if not name and isinstance(source, dict):  # imported: {"format": ..., "files": [...]}
        name = f"{source.get('format', 'imported')} ({path.name})"
    return str(name or source or path.name)


def dataset_stats(path: Path, progress: bool = False) -> dict[str, Any]:
    """All figures of a data set folder as one JSON-ready dict (see module doc). UserError if unreadable."""
    ds = Dataset(Path(path))
    if len(ds) == 0:
        raise UserError(f"{ds.path}: the data set lists no scenes; nothing to describe")
    frames = agent_frames = agents = 0
    by_type = np.zeros(NUM_TYPES, np.int64)
    speed_sum, speed_sq = np.zeros(NUM_TYPES), np.zeros(NUM_TYPES)
    lateral: list[list[np.ndarray]] = [[] for _ in range(NUM_TYPES)]
    lateral_source = set()
    neighbours = 0
    min_types, type_counts_sum = NUM_TYPES, 0
    ever = np.zeros(NUM_TYPES, bool)
    sim_collisions = teleports = 0
    box = {"vehicle-vehicle": 0, "vehicle-pedestrian": 0, "pedestrian-pedestrian": 0}
    agent_seconds, duration, dts = 0.0, 0.0, set()
    bar = tqdm(ds, total=len(ds), desc="stats", unit="scene", file=sys.stderr, leave=False,
               disable=not progress or len(ds) < 8)
    for scene in bar:
        valid = scene.valid
        frames += scene.num_frames
        duration += scene.num_frames * scene.dt
        dts.add(scene.dt)
        agent_frames += int(valid.sum())
        agent_seconds += float(valid.sum()) * scene.dt
        agents += int(valid.any(1).sum())
        per_frame = types_per_frame(scene.agent_type, valid)  # (types, T)
        by_type += per_frame.sum(1)
        present = (per_frame > 0).sum(0)
        if scene.num_frames:
            min_types = min(min_types, int(present.min()))
        type_counts_sum += int(present.sum())
        ever |= per_frame.sum(1) > 0
        types = np.broadcast_to(scene.agent_type[:, None], valid.shape)[valid].astype(np.int64)
        speed = scene.speed[valid].astype(np.float64)
        speed_sum += np.bincount(types, speed, NUM_TYPES)
        speed_sq += np.bincount(types, speed**2, NUM_TYPES)
        lat, source = lateral_values(scene)
        lateral_source.add(source)
        lat = lat[valid]
        order = np.argsort(types, kind="stable")
        for t, chunk in enumerate(np.split(lat[order], np.cumsum(np.bincount(types, minlength=NUM_TYPES))[:-1])):
            lateral[t].append(chunk)
        neighbours += int(neighbours_within(scene.xy, valid).sum())
        events = scene.meta.get("events", [])
        sim_collisions += sum(e.get("kind") == "collision" for e in events)
        teleports += sum(e.get("kind") == "teleport" for e in events)
        hits = collision_events(scene.xy, box_heading(scene), scene.length, scene.width, valid)
        kinds = pair_kind(scene.agent_type[hits[:, 1]], scene.agent_type[hits[:, 2]])
        for k in box:
            box[k] += int((kinds == k).sum())

    per_frame_by_type = by_type / max(frames, 1)
    spec = ds.info.get("spec")
    length = road_length_m(ds.road, spec)
    agents_per_frame = agent_frames / max(frames, 1)
    mean = speed_sum / np.maximum(by_type, 1)
    std = np.sqrt(np.maximum(speed_sq / np.maximum(by_type, 1) - mean**2, 0.0))
    agent_min = agent_seconds / 60.0
    box_total = box["vehicle-vehicle"] + box["vehicle-pedestrian"]

    def rate(n: int) -> float:
        return round(1000.0 * n / agent_min, 4) if agent_min else 0.0

    labels = [AgentType(t).label for t in range(NUM_TYPES)]
    lat_stats = {}
    for t in np.flatnonzero(by_type):
        v = np.concatenate(lateral[t]).astype(np.float64)
        lat_stats[labels[t]] = {"std": round(float(v.std()), 4), "p05": round(float(np.percentile(v, 5)), 3),
                                "p95": round(float(np.percentile(v, 95)), 3)}
    return {
        "dataset": str(ds.path),
        "scenario": dataset_name(ds.info, ds.path),
        "scenes": len(ds),
        "frames": frames,
        "dt": sorted(dts)[0] if len(dts) == 1 else sorted(dts),
        "duration_s": round(duration, 3),
        "agents": agents,
        "agent_frames": agent_frames,
        "agents_per_frame": round(agents_per_frame, 4),
        "agents_per_frame_by_type": {labels[t]: round(float(per_frame_by_type[t]), 4) for t in range(NUM_TYPES)},
        "distinct_types": int(ever.sum()),
        "distinct_types_per_frame": {"min": int(min_types) if frames else 0,
                                     "mean": round(type_counts_sum / max(frames, 1), 3)},
        "agents_within_50m": round(neighbours / max(agent_frames, 1), 4),
        "road_length_m": length,
        "density_per_km": round(agents_per_frame / (length / 1000.0), 3) if length else None,
        "speed_by_type": {labels[t]: {"mean": round(float(mean[t]), 3), "std": round(float(std[t]), 3)}
                          for t in np.flatnonzero(by_type)},
        "lateral_offset_by_type": lat_stats,
        "lateral_source": "/".join(sorted(lateral_source)),
        "agent_minutes": round(agent_min, 3),
        "collisions": {
            "simulator": sim_collisions,
            "box_overlap": box_total,
            "box_overlap_by_kind": box,
            "rate_per_1000_agent_min": {"simulator": rate(sim_collisions), "box_overlap": rate(box_total)},
            "note": "box_overlap: oriented-box overlaps computed from the data at the bodies' heading "
                    "(sim_heading where recorded; vehicle-vehicle plus vehicle-pedestrian, each contact spell "
                    "once); simulator: events the simulator reported",
        },
        "teleports": teleports,
    }


# ---------------------------------------------------------------------- printing
def format_table(s: dict[str, Any]) -> str:
    """The figures as text: a Table-1 row, then a per-type table, then collisions."""
    paper_order = [("pedestrian", "Ped"), ("bicycle", "Bicycle"), ("car", "Car"), ("motorcycle", "Bike"),
                   ("scooter", "Scooter"), ("bus", "Bus"), ("truck", "Truck"), ("rickshaw", "Rick")]
    per = s["agents_per_frame_by_type"]
    head = ["Dataset", "#Frames(x10^3)", *[h for _, h in paper_order], "Other", "Total", "Road(km)", "Density/km",
            "#Diff"]
    road = f"{s['road_length_m'] / 1000:.3f}" if s["road_length_m"] else "-"
    dens = f"{s['density_per_km']:.1f}" if s["density_per_km"] is not None else "-"
    row = [s["scenario"] or Path(s["dataset"]).name, f"{s['frames'] / 1000:.2f}",
           *[f"{per[k]:.2f}" for k, _ in paper_order], f"{per['other']:.2f}", f"{s['agents_per_frame']:.2f}", road,
           dens, str(s["distinct_types"])]
    widths = [max(len(a), len(b)) for a, b in zip(head, row, strict=True)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(head, widths, strict=True)),
             "  ".join(r.rjust(w) for r, w in zip(row, widths, strict=True)), ""]
    lines.append(f"scenes {s['scenes']}, {s['duration_s']:.0f} s recorded at dt {s['dt']} s, {s['agents']} agents; "
                 f"agents within 50 m: {s['agents_within_50m']:.1f}; distinct types per frame: min "
                 f"{s['distinct_types_per_frame']['min']}, mean {s['distinct_types_per_frame']['mean']:.2f}")
    lines.append("")
    lines.append(f"{'type':<11}{'agents/frame':>13}{'speed mean':>12}{'speed std':>11}"
                 f"{'lateral std':>13}{'lateral p05..p95 (' + s['lateral_source'] + ')':>36}")
    for label, sp in s["speed_by_type"].items():
        la = s["lateral_offset_by_type"][label]
        lines.append(f"{label:<11}{per[label]:>13.2f}{sp['mean']:>10.2f} m/s{sp['std']:>7.2f} m/s"
                     f"{la['std']:>11.2f} m{la['p05']:>26.2f} .. {la['p95']:.2f} m")
    c = s["collisions"]
    lines.append("")
    lines.append(f"collisions: simulator-reported {c['simulator']} "
                 f"({c['rate_per_1000_agent_min']['simulator']:.3f} per 1,000 agent-minutes); box overlaps "
                 f"{c['box_overlap']} ({c['rate_per_1000_agent_min']['box_overlap']:.3f} per 1,000 agent-minutes; "
                 f"vehicle-vehicle {c['box_overlap_by_kind']['vehicle-vehicle']}, vehicle-pedestrian "
                 f"{c['box_overlap_by_kind']['vehicle-pedestrian']}, pedestrian-pedestrian "
                 f"{c['box_overlap_by_kind']['pedestrian-pedestrian']} not counted) over "
                 f"{s['agent_minutes']:.0f} agent-minutes")
    lines.append(f"teleports: {s['teleports']}")
    return "\n".join(lines)


def write_frame_figure(path: Path, out: Path, scene_index: int = 0, frame: int | None = None) -> Path:
    """One frame of one scene top-down: footprints coloured by type, last 3 s of trails -> PNG."""
    from simharness.report import plot_frame

    ds = Dataset(Path(path))
    scene = ds.scene(scene_index)
    if frame is None:  # the busiest frame at least 3 s in, so trails are full length
        start = min(int(round(3.0 / scene.dt)), max(scene.num_frames - 1, 0))
        frame = start + int(np.argmax(scene.valid[:, start:].sum(0))) if scene.num_frames else 0
    road, window = ds.road, None
    if road is not None and road.drivable:
        x0, y0, x1, y1 = road.bounds()
        xs = np.sort(scene.xy[scene.valid[:, frame], frame, 0])
        if x1 - x0 > 2 * FIGURE_WINDOW_M and xs.size:  # a long road: show its busiest stretch, readable
            inside = np.searchsorted(xs, xs + FIGURE_WINDOW_M) - np.arange(xs.size)
            left = float(np.clip(xs[int(np.argmax(inside))] - 5.0, x0, x1 - FIGURE_WINDOW_M))
            window = (left, y0, left + FIGURE_WINDOW_M, y1)
    return plot_frame(scene, frame, out, road=road, window=window)


def stats_command(args: Any) -> int:
    """CLI: `simharness stats DIR [--json] [--figure PATH]`."""
    if args.figure is not None:  # before any work: a bad path costs nothing
        from simharness.io.folders import prepare_figure

        prepare_figure(args.figure)
    s = dataset_stats(args.data, progress=not args.json)
    print(json.dumps(s, sort_keys=True) if args.json else format_table(s))
    if args.figure is not None:
        out = write_frame_figure(args.data, args.figure)
        print(f"figure: {out}", file=sys.stderr if args.json else sys.stdout)
    return 0
