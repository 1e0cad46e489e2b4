"""A recorded data set as the world of a replay episode: its scenes in metres, the ego chosen by seed, and
the drivable area.

Choosing the ego (`choose_ego`): every (scene, agent) pair that qualifies is listed in a fixed order, and the
seed draws one uniformly (`numpy.random.default_rng(seed)`), so the same seed gives the same scene and agent
for every predictor. An agent qualifies when
- it is a vehicle (any type but pedestrian), or any agent where the data set holds no vehicle (ETH/UCY);
- it is present, without a gap, for the whole episode from its first frame (`duration` s);
- it stays away from the recording's edges: along its initial direction of travel, some recorded agent was
  seen at least `edge_margin` m behind its start and at least `edge_margin` m ahead of its end, so that it
  neither enters nor leaves the recorded area during the episode (where the traffic around it is unknown);
- its recorded box overlaps no other agent's during the episode: an annotation that leaves an agent no room
  (pedestrians walking arm in arm, boxes drawn loosely) is a collision no driver could avoid.

The drivable area (`drivable_area`): where the vehicles drove (where none drove: where the agents went), every
recorded box rasterised on a `cell` m grid, closed and widened by one cell, its outline traced as polygons; joined
with the data set's own road where it has one (CommonRoad lanelets), which recorded vehicles leave for shoulders
and ramps the map's crop cuts off (7% of NGSIM US-101's agent-frames in one of the samples).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from simharness.errors import UserError
from simharness.scene import AgentType, Scene
from simharness.sim.base import RoadGeometry


@dataclasses.dataclass(frozen=True)
class Recording:
    """The scenes of a data set, in metres, with their roads (one per scene)."""

    scenes: tuple[Scene, ...]
    roads: tuple[RoadGeometry, ...]
    source: str
    pairs: dict[tuple[int, float], list[tuple[int, int]]] = dataclasses.field(default_factory=dict, compare=False)

    @staticmethod
    def load(path: str | Path, pixel_scale: float = 0.0, key: str = "replay.pixel_scale") -> Recording:
        """Read a data set folder; scenes in pixels are scaled by `pixel_scale` m/px, or refused without one."""
        from simharness.io.parquet import Dataset

        ds = Dataset(Path(path))
        scenes, roads = [], []
        shared_road = ds.road
        for scene in ds:
            if scene.units != "m":
                if not pixel_scale > 0:
                    raise UserError(f"{path}: scene {scene.meta.get('scene_id', '')!r} is recorded in "
                                    f"{scene.units}, not metres; set {key} (metres per {scene.units}) to replay it")
                scene = scene.replace(xy=scene.xy * pixel_scale, speed=scene.speed * pixel_scale,
                                      length=scene.length * pixel_scale, width=scene.width * pixel_scale,
                                      meta={**scene.meta, "units": "m", "pixel_scale": pixel_scale})
            road = RoadGeometry.from_dict(scene.meta["road"]) if scene.meta.get("road") else shared_road
            tracks = drivable_area(scene)
            if road is None or not road.drivable or scene.meta.get("pixel_scale"):
                road = tracks
            else:  # recorded vehicles also drive where the map has no lane (shoulders, ramps cut off by the crop)
                road = dataclasses.replace(road, drivable=road.drivable + tracks.drivable)
            scenes.append(scene)
            roads.append(road)
        if not scenes:
            raise UserError(f"{path}: the data set holds no scene to replay")
        return Recording(tuple(scenes), tuple(roads), str(path))


def candidates(scene: Scene, frames: int, edge_margin: float) -> np.ndarray:
    """Rows of `scene` that may become the ego of an episode of `frames` frames (module docstring).

    -> (K,) int rows, in row order.
    """
    va = scene.valid
    n, t = va.shape
    if n == 0 or t < frames:
        return np.zeros(0, int)
    vehicles = scene.agent_type != int(AgentType.PEDESTRIAN)
    kind = vehicles if vehicles.any() else np.ones(n, bool)
    first = np.argmax(va, 1)
    idx = np.minimum(first[:, None] + np.arange(frames)[None], t - 1)
    whole = va.any(1) & (first + frames <= t) & np.take_along_axis(va, idx, 1).all(1)
    ok = kind & whole
    rows = np.flatnonzero(ok)
    if rows.size == 0:
        return rows
    start = scene.xy[rows, first[rows]].astype(np.float64)  # (K, 2)
    end = scene.xy[rows, first[rows] + frames - 1].astype(np.float64)
    move = end - start
    dist = np.linalg.norm(move, axis=1)
    fwd = np.where(dist[:, None] > 1e-3, move / np.maximum(dist, 1e-3)[:, None],
                   np.stack([np.cos(scene.heading[rows, first[rows]]), np.sin(scene.heading[rows, first[rows]])], -1))
    seen = scene.xy[va].astype(np.float64)  # (V, 2) every recorded position
    along = seen @ fwd.T  # (V, K)
    s0, s1 = (start * fwd).sum(1), (end * fwd).sum(1)
    inside = (along.min(0) <= s0 - edge_margin) & (along.max(0) >= s1 + edge_margin)
    rows = rows[inside]
    clear = [not _overlaps(scene, int(r), int(first[r]), frames) for r in rows]  # one check per candidate, at load
    return rows[np.asarray(clear, bool)] if rows.size else rows


def _overlaps(scene: Scene, row: int, start: int, frames: int) -> bool:
    """Whether agent `row`'s recorded box overlaps another's in frames [start, start + frames)."""
    from simharness.metrics import collisions, safety

    part = scene.slice_frames(start, start + frames)
    contact = safety.ego_contact(part.xy, collisions.box_heading(part), part.length, part.width, part.valid, row)
    return bool(contact.any())


def choose_ego(recording: Recording, seed: int, frames: int, edge_margin: float) -> tuple[int, int]:
    """(scene index, agent row) of seed's episode: one draw among every qualifying pair (module docstring)."""
    key = (frames, float(edge_margin))
    if key not in recording.pairs:  # the same list for every seed: built once per recording
        recording.pairs[key] = [(i, int(r)) for i, s in enumerate(recording.scenes)
                                for r in candidates(s, frames, edge_margin)]
    pairs = recording.pairs[key]
    if not pairs:
        raise UserError(f"{recording.source}: no agent is present for a whole {frames}-frame episode away from the "
                        "recording's edges; shorten `duration` or lower `replay.edge_margin`")
    return pairs[int(np.random.default_rng(int(seed)).integers(len(pairs)))]


def drivable_area(scene: Scene, cell: float = 1.0) -> RoadGeometry:
    """Where the vehicles (else all agents) went, as drivable polygons (module docstring)."""
    from contourpy import contour_generator
    from scipy import ndimage

    vehicles = scene.agent_type != int(AgentType.PEDESTRIAN)
    rows = vehicles if (vehicles[:, None] & scene.valid).any() else np.ones(scene.num_agents, bool)
    va = scene.valid & rows[:, None]
    if not va.any():
        return RoadGeometry()
    xy = scene.xy[va].astype(np.float64)  # (V, 2)
    h = scene.heading[va].astype(np.float64)
    ln = np.broadcast_to(scene.length[:, None], va.shape)[va].astype(np.float64)
    wd = np.broadcast_to(scene.width[:, None], va.shape)[va].astype(np.float64)
    # Sample each box on a grid of points at most `cell` / 2 apart, so every cell it covers gets a point.
    u = np.linspace(-0.5, 0.5, max(2, int(np.ceil(ln.max() / (cell / 2))) + 1))
    w = np.linspace(-0.5, 0.5, max(2, int(np.ceil(wd.max() / (cell / 2))) + 1))
    fwd = np.stack([np.cos(h), np.sin(h)], -1)
    left = np.stack([-np.sin(h), np.cos(h)], -1)
    pts = (xy[:, None, None] + (u[None, :, None, None] * ln[:, None, None, None]) * fwd[:, None, None]
           + (w[None, None, :, None] * wd[:, None, None, None]) * left[:, None, None]).reshape(-1, 2)
    lo = pts.min(0) - 3 * cell
    shape = (np.ceil((pts.max(0) + 3 * cell - lo) / cell)).astype(int) + 1
    grid = np.zeros(shape[::-1], bool)  # (rows = y, cols = x)
    ij = ((pts - lo) / cell).astype(int)
    grid[ij[:, 1], ij[:, 0]] = True
    grid = ndimage.binary_closing(grid, iterations=2)
    grid = ndimage.binary_dilation(grid, iterations=1)
    x = lo[0] + cell * np.arange(shape[0])
    y = lo[1] + cell * np.arange(shape[1])
    lines = contour_generator(x, y, grid.astype(np.float64)).lines(0.5)
    polys = tuple(np.asarray(p, np.float64) for p in lines if len(p) >= 4)
    return RoadGeometry(drivable=polys)
