"""The Simulator protocol every backend follows, and the `Frame` it emits.

A simulator advances in recorded frames (1 / record_hz seconds, possibly
several internal steps each). `reset(seed)` builds the world, runs the
warm-up unrecorded and returns the first recorded frame (t = 0).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simharness.scene import Scene, stack_frames


@dataclasses.dataclass(frozen=True)
class Event:
    """Something the simulator itself reported (never used for scoring, only recorded).

    kind: "collision" | "teleport" | "emergency_stop"
    t: seconds since the start of recording
    agent_id / other_id: the agents involved ("" when none)
    detail: backend-specific text (e.g. SUMO's collision type)
    """

    kind: str
    t: float
    agent_id: str
    other_id: str = ""
    detail: str = ""


DRIFT_FULL_SPEED = 4.0  # m/s: an ego this fast may move sideways at its type's full lateral speed
EGO_MAX_DECEL = 7.0  # m/s^2: the ego's hardest braking (the planners' `EgoLimits.max_decel`)


def ego_lateral_limit(lateral_max: Any, speed_before: Any, speed_after: Any) -> Any:
    """m/s: the fastest sideways motion of a commanded ego over one step, on every backend.

    lateral_max: the type's lateral speed (m/s); speed_before / speed_after: forward speed (m/s) at the step's start
    and end; floats or arrays. Scaled by the lower speed over DRIFT_FULL_SPEED (at most 1): no sideways motion without
    forward speed, so the ego's body (its heading is its direction of motion) never turns more than
    atan(lateral_max / DRIFT_FULL_SPEED) off its line, even as it brakes to a stop.
    """
    return lateral_max * np.clip(np.minimum(speed_before, speed_after) / DRIFT_FULL_SPEED, 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class EgoCommand:
    """What the harness tells the ego for the next recorded frame.

    acceleration: longitudinal, m/s^2 (clipped by the backend to the ego type's limits)
    lateral_velocity: m/s, positive to the left of the ego's heading
    """

    acceleration: float = 0.0
    lateral_velocity: float = 0.0


@dataclasses.dataclass(frozen=True, eq=False)
class Frame:
    """All agents at one recorded instant, in `Scene` field names (n agents).

    t:          seconds since the start of recording
    agent_id:   (n,) str
    agent_type: (n,) int8
    xy:         (n, 2) float32 metres
    heading:    (n,) float32 radians CCW from +x (direction of motion)
    speed:      (n,) float32 m/s
    length:     (n,) float32 metres
    width:      (n,) float32 metres
    ego:        index of the ego in this frame, or -1
    extra:      name -> (n,) float32 backend extras (e.g. "sim_heading")
    events:     what the simulator reported since the previous frame
    """

    t: float
    agent_id: np.ndarray
    agent_type: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    width: np.ndarray
    ego: int = -1
    extra: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    events: tuple[Event, ...] = ()

    @property
    def num_agents(self) -> int:
        return len(self.agent_id)


@dataclasses.dataclass(frozen=True)
class RoadGeometry:
    """Static road layout for plots and off-road checks, world frame, metres.

    drivable:  polygons (K, 2) of the carriageway(s)
    sidewalks: polygons (K, 2)
    markings:  polylines (K, 2) of lane lines / edges to draw
    """

    drivable: tuple[np.ndarray, ...] = ()
    sidewalks: tuple[np.ndarray, ...] = ()
    markings: tuple[np.ndarray, ...] = ()

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) over all shapes."""
        pts = np.concatenate([*self.drivable, *self.sidewalks, *self.markings] or [np.zeros((1, 2))])
        return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()),
                float(pts[:, 1].max()))

    def on_road(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) points -> (...) bool, inside any drivable polygon."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        inside = np.zeros(len(pts), bool)
        for path in self._drivable_paths:
            inside |= path.contains_points(pts, radius=1e-6)
        return inside.reshape(np.shape(xy)[:-1])

    @functools.cached_property
    def _drivable_paths(self) -> tuple[Any, ...]:
        """The drivable polygons as matplotlib paths, built once (the planner tests points every frame)."""
        from matplotlib.path import Path as MplPath

        return tuple(MplPath(poly) for poly in self.drivable)

    def to_dict(self) -> dict[str, Any]:
        return {k: [np.round(p, 3).tolist() for p in getattr(self, k)]
                for k in ("drivable", "sidewalks", "markings")}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> RoadGeometry:
        return RoadGeometry(**{k: tuple(np.asarray(p, dtype=np.float64) for p in d.get(k, ()))
                               for k in ("drivable", "sidewalks", "markings")})


@runtime_checkable
class Simulator(Protocol):
    """One running simulation. libsumo allows one per process: use a process per job."""

    dt: float  # seconds per recorded frame
    road: RoadGeometry

    def reset(self, seed: int) -> Frame: ...

    def step(self, ego_command: EgoCommand | None = None) -> Frame: ...

    def close(self) -> None: ...


def scene_from_frames(frames: Sequence[Frame], dt: float, meta: dict[str, Any] | None = None) -> Scene:
    """Dense `Scene` from recorded frames; rows in order of first appearance.

    Per-agent constants (type, footprint) are taken from each agent's first frame;
    simulator events are kept in `meta["events"]` as dicts.
    """
    ids = [f.agent_id for f in frames]
    cols: dict[str, list[np.ndarray]] = {
        "xy": [f.xy for f in frames], "heading": [f.heading for f in frames],
        "speed": [f.speed for f in frames], "agent_type": [f.agent_type for f in frames],
        "length": [f.length for f in frames], "width": [f.width for f in frames],
    }
    extra_keys = sorted({k for f in frames for k in f.extra})
    for k in extra_keys:
        cols["extra:" + k] = [f.extra.get(k, np.zeros(f.num_agents, np.float32)) for f in frames]
    agent_id, valid, dense, first = stack_frames(ids, cols)
    rows = np.arange(len(agent_id))
    ego_ids = {f.agent_id[f.ego] for f in frames if f.ego >= 0}
    ego = int(np.flatnonzero(np.isin(agent_id, list(ego_ids)))[0]) if ego_ids else -1
    meta = dict(meta or {})
    meta["events"] = [dataclasses.asdict(e) for f in frames for e in f.events]
    return Scene(
        xy=dense["xy"], heading=dense["heading"], speed=dense["speed"], valid=valid,
        agent_id=agent_id, agent_type=dense["agent_type"][rows, first],
        length=dense["length"][rows, first], width=dense["width"][rows, first], dt=dt, ego=ego,
        extra={k: dense["extra:" + k] for k in extra_keys}, meta=meta,
    )
