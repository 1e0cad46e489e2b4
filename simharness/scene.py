"""The one data type: `Scene`, dense masked arrays of agents over frames.

Layout as in Waymax: one row per agent, one column per frame, every array
beside a `valid` mask. Units are SI (metres, seconds, radians) unless
`meta["units"]` says otherwise (an importer of pixel data sets it to "px").

Also here, because predictors import this module and nothing else of the
harness: `Forecast`, the output of every predictor, and the `Predictor`
protocol.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simharness.errors import UserError


class AgentType(enum.IntEnum):
    """Road agent classes of dense heterogeneous traffic (stored as int8)."""

    CAR = 0
    BUS = 1
    TRUCK = 2
    RICKSHAW = 3
    MOTORCYCLE = 4
    SCOOTER = 5
    BICYCLE = 6
    PEDESTRIAN = 7
    OTHER = 8

    @property
    def label(self) -> str:
        """Lowercase name, as stored on disk and written in scenario files."""
        return self.name.lower()

    @property
    def footprint(self) -> tuple[float, float]:
        """Default (length, width) in metres."""
        return DEFAULT_FOOTPRINT[self]

    @classmethod
    def parse(cls, name: str | int) -> AgentType:
        """`AgentType` from its lowercase name or code; UserError naming the choices otherwise."""
        if isinstance(name, (int, np.integer)) and not isinstance(name, bool):
            if int(name) in cls._value2member_map_:
                return cls(int(name))
        elif isinstance(name, str) and name.strip().upper() in cls.__members__:
            return cls[name.strip().upper()]
        raise UserError(f"unknown agent type {name!r}; expected one of {', '.join(LABELS)}")


# Typical footprints (length, width) in metres: Indian/Asian urban fleet sizes.
DEFAULT_FOOTPRINT: dict[AgentType, tuple[float, float]] = {
    AgentType.CAR: (4.3, 1.8),
    AgentType.BUS: (12.0, 2.55),
    AgentType.TRUCK: (8.5, 2.5),
    AgentType.RICKSHAW: (2.7, 1.4),
    AgentType.MOTORCYCLE: (2.0, 0.8),
    AgentType.SCOOTER: (1.8, 0.7),
    AgentType.BICYCLE: (1.7, 0.6),
    AgentType.PEDESTRIAN: (0.5, 0.5),
    AgentType.OTHER: (4.0, 1.8),
}
LABELS: tuple[str, ...] = tuple(t.label for t in AgentType)
VEHICLE_TYPES: tuple[AgentType, ...] = tuple(t for t in AgentType if t not in (AgentType.PEDESTRIAN,))


def agent_types_from_labels(labels: Sequence[str] | np.ndarray) -> np.ndarray:
    """(N,) lowercase names -> (N,) int8 codes; UserError on an unknown name."""
    labels = np.asarray(labels, dtype=object)
    uniq, inverse = np.unique(labels.astype(str), return_inverse=True)
    codes = np.array([AgentType.parse(u) for u in uniq], dtype=np.int8)
    return codes[inverse].astype(np.int8)


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """Agents over frames, dense and masked.

    Shapes: N agents, T frames. Invalid entries hold zeros and must be ignored.

    xy:         (N, T, 2) float32  centre position, metres, world frame
    heading:    (N, T)    float32  radians, counter-clockwise from +x
    speed:      (N, T)    float32  m/s
    valid:      (N, T)    bool     agent present at that frame
    agent_id:   (N,)      str      stable id within the scene
    agent_type: (N,)      int8     `AgentType`
    length:     (N,)      float32  footprint, metres
    width:      (N,)      float32  footprint, metres
    dt:         seconds per frame
    ego:        row of the ego agent, or -1
    frame0:     index of column 0 in the source recording (kept through slicing)
    extra:      optional per-agent-frame arrays, each (N, T) float32, e.g. the
                simulator's own heading when it differs from the motion heading
    meta:       source, scenario, seed, backend, versions, config hash, units, events
    """

    xy: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    valid: np.ndarray
    agent_id: np.ndarray
    agent_type: np.ndarray
    length: np.ndarray
    width: np.ndarray
    dt: float
    ego: int = -1
    frame0: int = 0
    extra: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        # Coerce dtypes once here so every consumer can rely on them.
        set_ = object.__setattr__
        set_(self, "xy", np.asarray(self.xy, dtype=np.float32))
        set_(self, "heading", np.asarray(self.heading, dtype=np.float32))
        set_(self, "speed", np.asarray(self.speed, dtype=np.float32))
        set_(self, "valid", np.asarray(self.valid, dtype=bool))
        set_(self, "agent_id", np.asarray(self.agent_id, dtype=object).astype(str))
        set_(self, "agent_type", np.asarray(self.agent_type, dtype=np.int8))
        set_(self, "length", np.asarray(self.length, dtype=np.float32))
        set_(self, "width", np.asarray(self.width, dtype=np.float32))
        set_(self, "extra", {k: np.asarray(v, dtype=np.float32) for k, v in self.extra.items()})
        set_(self, "dt", float(self.dt))
        set_(self, "ego", int(self.ego))
        set_(self, "frame0", int(self.frame0))
        self.validate()

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise ValueError if shapes or values are inconsistent."""
        if self.xy.ndim != 3 or self.xy.shape[2] != 2:
            raise ValueError(f"Scene.xy must be (N, T, 2), got {self.xy.shape}")
        n, t = self.xy.shape[:2]
        for name in ("heading", "speed", "valid", *(f"extra[{k}]" for k in self.extra)):
            arr = self.extra[name[6:-1]] if name.startswith("extra[") else getattr(self, name)
            if arr.shape != (n, t):
                raise ValueError(f"Scene.{name} must be ({n}, {t}), got {arr.shape}")
        for name in ("agent_id", "agent_type", "length", "width"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"Scene.{name} must be ({n},), got {getattr(self, name).shape}")
        if not self.dt > 0:
            raise ValueError(f"Scene.dt must be positive, got {self.dt}")
        if not -1 <= self.ego < max(n, 0) and not (n == 0 and self.ego == -1):
            raise ValueError(f"Scene.ego must be -1 or a row in [0, {n}), got {self.ego}")
        if n and (self.agent_type.min() < 0 or self.agent_type.max() >= len(AgentType)):
            raise ValueError("Scene.agent_type holds codes outside AgentType")
        if len(set(self.agent_id.tolist())) != n:
            raise ValueError("Scene.agent_id must be unique within a scene")

    # ------------------------------------------------------------------ shape
    @property
    def num_agents(self) -> int:
        return int(self.xy.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.xy.shape[1])

    @property
    def times(self) -> np.ndarray:
        """(T,) float64 seconds of each column in the source recording."""
        return (self.frame0 + np.arange(self.num_frames)) * self.dt

    @property
    def units(self) -> str:
        """"m" unless an importer recorded otherwise (e.g. "px")."""
        return str(self.meta.get("units", "m"))

    @property
    def velocity(self) -> np.ndarray:
        """(N, T, 2) float32 finite-difference velocity, units/s; zero where undefined."""
        vel = np.zeros_like(self.xy)
        both = self.valid[:, 1:] & self.valid[:, :-1]
        step = (self.xy[:, 1:] - self.xy[:, :-1]) / self.dt
        vel[:, 1:] = np.where(both[..., None], step, 0.0)
        # First valid frame of a track copies the next difference.
        first = self.valid[:, :-1] & ~np.pad(self.valid, ((0, 0), (1, 0)))[:, :-2] & both
        vel[:, :-1] = np.where(first[..., None], step, vel[:, :-1])
        return vel

    # ------------------------------------------------------------------ slicing
    def replace(self, **changes: Any) -> Scene:
        return dataclasses.replace(self, **changes)

    def slice_frames(self, start: int, stop: int | None = None) -> Scene:
        """Columns [start, stop) as a new Scene (views, not copies); agents kept."""
        stop = self.num_frames if stop is None else stop
        s = slice(start, stop)
        return self.replace(
            xy=self.xy[:, s],
            heading=self.heading[:, s],
            speed=self.speed[:, s],
            valid=self.valid[:, s],
            extra={k: v[:, s] for k, v in self.extra.items()},
            frame0=self.frame0 + range(self.num_frames)[s].start,
        )

    def select_agents(self, rows: np.ndarray | Sequence[int]) -> Scene:
        """Rows (indices or an (N,) bool mask) as a new Scene; ego remapped or -1."""
        rows = np.asarray(rows)
        if rows.dtype == bool:
            rows = np.flatnonzero(rows)
        ego = -1
        if self.ego >= 0:
            hit = np.flatnonzero(rows == self.ego)
            ego = int(hit[0]) if hit.size else -1
        return self.replace(
            xy=self.xy[rows],
            heading=self.heading[rows],
            speed=self.speed[rows],
            valid=self.valid[rows],
            agent_id=self.agent_id[rows],
            agent_type=self.agent_type[rows],
            length=self.length[rows],
            width=self.width[rows],
            extra={k: v[rows] for k, v in self.extra.items()},
            ego=ego,
        )

    def drop_empty_agents(self) -> Scene:
        """Remove agents with no valid frame (after slicing)."""
        return self.select_agents(self.valid.any(axis=1))

    def equals(self, other: Scene, meta: bool = False) -> bool:
        """Exact equality of all arrays (and of meta if asked); invalid entries compared too."""
        arrays = ("xy", "heading", "speed", "valid", "agent_id", "agent_type", "length", "width")
        same = all(np.array_equal(getattr(self, a), getattr(other, a)) for a in arrays)
        same &= self.extra.keys() == other.extra.keys() and all(
            np.array_equal(v, other.extra[k]) for k, v in self.extra.items()
        )
        same &= (self.dt, self.ego, self.frame0) == (other.dt, other.ego, other.frame0)
        return bool(same and (not meta or self.meta == other.meta))

    @staticmethod
    def empty(dt: float, num_frames: int = 0, meta: dict[str, Any] | None = None) -> Scene:
        z = np.zeros((0, num_frames), np.float32)
        return Scene(
            xy=np.zeros((0, num_frames, 2), np.float32), heading=z, speed=z, valid=z.astype(bool),
            agent_id=np.zeros(0, str), agent_type=np.zeros(0, np.int8), length=np.zeros(0),
            width=np.zeros(0), dt=dt, meta=dict(meta or {}),
        )


def heading_velocity(speed: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """speed (...) units/s (or units per frame) along heading (...) rad -> (..., 2) velocity in the same units."""
    return np.asarray(speed)[..., None] * np.stack([np.cos(heading), np.sin(heading)], -1)


def stack_frames(
    agent_ids: Sequence[np.ndarray],
    columns: dict[str, Sequence[np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Scatter per-frame agent arrays into dense (N, T, ...) arrays.

    agent_ids: T arrays of (n_t,) str ids present at each frame.
    columns:   name -> T arrays of (n_t, ...) values, aligned with agent_ids.
    Returns (ids (N,) in order of first appearance, valid (N, T),
             name -> (N, T, ...) arrays, first (N,) frame of first appearance).
    """
    num_frames = len(agent_ids)
    flat_ids = np.concatenate([np.asarray(a, dtype=object) for a in agent_ids]) if num_frames else np.zeros(0)
    frame_of = np.repeat(np.arange(num_frames), [len(a) for a in agent_ids])
    uniq, first_pos, inverse = np.unique(flat_ids.astype(str), return_index=True, return_inverse=True)
    order = np.argsort(first_pos, kind="stable")  # rows in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    rows = rank[inverse]
    valid = np.zeros((uniq.size, num_frames), bool)
    valid[rows, frame_of] = True
    dense = {}
    for name, per_frame in columns.items():
        flat = np.concatenate([np.asarray(v) for v in per_frame]) if num_frames else np.zeros(0)
        out = np.zeros((uniq.size, num_frames, *flat.shape[1:]), dtype=flat.dtype)
        out[rows, frame_of] = flat
        dense[name] = out
    return uniq[order], valid, dense, frame_of[first_pos[order]] if uniq.size else np.zeros(0, int)


# ---------------------------------------------------------------------- forecasts
@dataclasses.dataclass(frozen=True, eq=False)
class Forecast:
    """A predictor's output for M target agents over F future frames, world frame.

    agent_id:  (M,)          str      targets, in the order asked for
    mean:      (M, F, 2)     float32  most likely (or mean) positions
    sigma_rho: (M, F, 3)     float32  optional (sigma_x, sigma_y, rho) of a bivariate Gaussian
    modes:     (M, K, F, 2)  float32  optional K sampled or multi-modal futures
    probs:     (M, K)        float32  optional mode probabilities
    dt:        seconds per future frame
    """

    agent_id: np.ndarray
    mean: np.ndarray
    dt: float
    sigma_rho: np.ndarray | None = None
    modes: np.ndarray | None = None
    probs: np.ndarray | None = None

    def __post_init__(self) -> None:
        m = len(self.agent_id)
        if self.mean.ndim != 3 or self.mean.shape[0] != m or self.mean.shape[2] != 2:
            raise ValueError(f"Forecast.mean must be ({m}, F, 2), got {self.mean.shape}")
        f = self.mean.shape[1]
        if self.sigma_rho is not None and self.sigma_rho.shape != (m, f, 3):
            raise ValueError(f"Forecast.sigma_rho must be ({m}, {f}, 3), got {self.sigma_rho.shape}")
        if self.modes is not None and (self.modes.ndim != 4 or self.modes.shape[::2] != (m, f)):
            raise ValueError(f"Forecast.modes must be ({m}, K, {f}, 2), got {self.modes.shape}")

    @property
    def horizon(self) -> int:
        return int(self.mean.shape[1])


@runtime_checkable
class Predictor(Protocol):
    """Anything that forecasts: TraPHic, a baseline, or a user's own model.

    history: the last H frames of all agents (column -1 is "now").
    targets: (M,) rows of `history` to forecast.
    horizon: number of future frames, each `history.dt` long.
    """

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast: ...
