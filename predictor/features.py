"""Prediction windows and TraPHic's inputs: the state space, neighbourhood, horizon and their grids.

Per agent and time step the state Omega (section 3 of the paper) is, in the *target* agent's frame
(origin at its current position, x along its current heading, y to its left, metres):

    x, y, vx, vy            position Psi and velocity dPsi
    concentration           agents in a box ahead of the agent (traffic concentration c(x, y))
    length, width           agent size l
    type one-hot (9)        agent class (heterogeneity)
    present                 1 where the agent exists at that step (histories may be partial)
    rel_vx, rel_vy          velocity relative to the target at the same step (driver behaviour)
    distance                distance to the target at the same step (driver behaviour)

The neighbourhood N_i is an ellipse around the agent, the horizon H_i a smaller semi-ellipse ahead
of it; each keeps a fixed number of nearest agents, placed on a spatial grid (cells in metres in
the agent's frame) that the model turns into the neighbour map and the horizon map.

Everything is vectorised over all agents of a frame; a data set's per-agent-frame arrays and its
sample index are built once (`FeatureStore.build`) and cached (predictor.windows_cache), so a training
batch is a handful of numpy gathers. Inference builds a store of one frame by the same code.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.scene import AgentType, Scene, heading_velocity

FEATURES_VERSION = 2  # the layout of windows and their cache
TYPE_NAMES = tuple(f"type_{t.label}" for t in AgentType)
FEATURES: tuple[str, ...] = ("x", "y", "vx", "vy", "concentration", "length", "width", *TYPE_NAMES,
                             "present", "rel_vx", "rel_vy", "distance")
NUM_FEATURES = len(FEATURES)
# Psi only (positions and presence): the state of the paper's variants without heterogeneous interactions.
HOMOGENEOUS_FEATURES: tuple[int, ...] = tuple(FEATURES.index(f) for f in ("x", "y", "present"))
_PRESENT = FEATURES.index("present")


@dataclasses.dataclass(frozen=True)
class WindowConfig:
    """Windows and interaction regions. Lengths are metres; scenes in other units are scaled by `length_scale`.

    history_s / future_s: seconds of history (incl. "now") and of future to predict.
    hz: sample rate of windows; the step in recorded frames is round(1 / (hz dt)).
    downsample: the paper's down-sampling for dense data: if set, the step in recorded frames
        (e.g. 2 on TRAF), overriding hz.
    stride: recorded frames between consecutive training windows ("now"s).
    neighbour_axes: semi-axes (along heading, lateral) of the neighbourhood ellipse.
    horizon_axes: semi-axes (ahead, lateral) of the horizon semi-ellipse (in front only).
    max_neighbours / max_horizon: the fixed number of nearest agents kept in each region.
    neighbour_grid / horizon_grid: cells (along, lateral) of the maps over each region's bounding box.
    concentration_box: (length ahead, width) of the box in which traffic concentration is counted.
    heading_window_s / min_motion: an agent's frame heading is its direction of motion over the last
        heading_window_s if it moved more than min_motion metres, else the scene's heading (stationary).
    length_scale: scene units per metre (None: 1 for metres, else meta["units_per_m"] of the scene).
    """

    history_s: float = 3.0
    future_s: float = 5.0
    hz: float = 5.0
    downsample: int | None = None
    stride: int = 1
    neighbour_axes: tuple[float, float] = (20.0, 6.0)
    horizon_axes: tuple[float, float] = (15.0, 4.5)
    max_neighbours: int = 12
    max_horizon: int = 6
    neighbour_grid: tuple[int, int] = (13, 5)
    horizon_grid: tuple[int, int] = (7, 5)
    concentration_box: tuple[float, float] = (10.0, 3.0)
    heading_window_s: float = 1.0
    min_motion: float = 0.5
    length_scale: float | None = None

    def step(self, dt: float) -> int:
        """Recorded frames per window step for data recorded every `dt` seconds."""
        if self.downsample is not None:
            return int(self.downsample)
        ratio = 1.0 / (self.hz * dt)
        if ratio < 0.999 or abs(ratio - round(ratio)) > 1e-3:
            raise UserError(f"window rate {self.hz:g} Hz needs data recorded at a whole multiple of it; "
                            f"the data has dt = {dt:g} s ({1 / dt:g} Hz)")
        return int(round(ratio))

    def frames(self, dt: float) -> tuple[int, int]:
        """(history frames incl. now, future frames) at the window rate for data with `dt`."""
        sdt = self.step(dt) * dt
        return int(round(self.history_s / sdt)), int(round(self.future_s / sdt))

    def scale_for(self, scene: Scene) -> float:
        """Scene units per metre."""
        if self.length_scale is not None:
            return float(self.length_scale)
        if scene.units == "m":
            return 1.0
        if "units_per_m" in scene.meta:
            return float(scene.meta["units_per_m"])
        raise UserError(f"scene {scene.meta.get('scene_id', '')!r} is in {scene.units!r}, not metres, and records no "
                        "pixels-per-metre scale (meta['units_per_m']), which sizes the ellipses and grids; "
                        "re-import it with `simharness import traf ... --pixel-scale M_PER_PX` (or --type-default car)")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> WindowConfig:
        names = {f.name for f in dataclasses.fields(WindowConfig)}
        unknown = set(d) - names
        if unknown:
            raise UserError(f"window config: unknown keys {sorted(unknown)}; expected some of {sorted(names)}")
        return WindowConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


# ---------------------------------------------------------------------------- per-frame geometry
def to_local(xy: np.ndarray, origin: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Points into frames: xy (..., 2), origin (..., 2), heading (...) -> (..., 2) (along, left)."""
    c, s = np.cos(heading), np.sin(heading)
    d = xy - origin
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)


def to_world(local: np.ndarray, origin: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Inverse of `to_local`: local (..., 2) -> world (..., 2)."""
    c, s = np.cos(heading), np.sin(heading)
    return np.stack([c * local[..., 0] - s * local[..., 1], s * local[..., 0] + c * local[..., 1]], -1) + origin


def concentration(xy: np.ndarray, heading: np.ndarray, box: tuple[float, float]) -> np.ndarray:
    """Traffic concentration: agents in the box ahead of each agent (0 < along <= L, |lateral| <= W/2).

    xy (n, 2) metres, heading (n,) -> (n,) float32 counts (the agent itself excluded).
    """
    rel = to_local(xy[None, :, :], xy[:, None, :], heading[:, None])  # (n, n, 2): j in i's frame
    inside = (rel[..., 0] > 0) & (rel[..., 0] <= box[0]) & (np.abs(rel[..., 1]) <= box[1] / 2)
    return inside.sum(1).astype(np.float32)


def select_neighbours(xy: np.ndarray, heading: np.ndarray, cfg: WindowConfig) -> dict[str, np.ndarray]:
    """Neighbourhood (ellipse) and horizon (semi-ellipse ahead) of every agent of one frame.

    xy (n, 2) metres, heading (n,) radians.
    Returns "nbr" (n, Kn) and "hz" (n, Kh) int rows of the nearest agents inside each region, nearest
    first, -1 padded; "nbr_cell" / "hz_cell" (n, K) int cell index (along * lateral_cells + lateral)
    on each region's grid, -1 padded.
    """
    n = len(xy)
    rel = to_local(xy[None, :, :], xy[:, None, :], heading[:, None])  # (n, n, 2)
    dist = np.hypot(rel[..., 0], rel[..., 1])
    other = ~np.eye(n, dtype=bool)
    (a, b), (ah, bh) = cfg.neighbour_axes, cfg.horizon_axes
    in_nbr = other & ((rel[..., 0] / a) ** 2 + (rel[..., 1] / b) ** 2 <= 1.0)
    in_hz = other & (rel[..., 0] > 0) & ((rel[..., 0] / ah) ** 2 + (rel[..., 1] / bh) ** 2 <= 1.0)
    out: dict[str, np.ndarray] = {}
    for key, inside, k, grid, lo in (("nbr", in_nbr, cfg.max_neighbours, cfg.neighbour_grid, -a),
                                     ("hz", in_hz, cfg.max_horizon, cfg.horizon_grid, 0.0)):
        d, rel_k = np.where(inside, dist, np.inf), rel
        if n < k:  # fewer agents than slots: pad with never-selected columns
            d = np.pad(d, ((0, 0), (0, k - n)), constant_values=np.inf)
            rel_k = np.pad(rel, ((0, 0), (0, k - n), (0, 0)))
        order = np.argsort(d, axis=1, kind="stable")[:, :k]
        keep = np.take_along_axis(d, order, 1) < np.inf
        rows = np.where(keep, order, -1)
        along_len = (a - lo, 2 * b) if key == "nbr" else (ah, 2 * bh)
        half_lat = b if key == "nbr" else bh
        pos = np.take_along_axis(rel_k, order[..., None], 1)  # (n, k, 2)
        ix = np.clip(np.floor((pos[..., 0] - lo) / along_len[0] * grid[0]), 0, grid[0] - 1).astype(np.int64)
        iy = np.clip(np.floor((pos[..., 1] + half_lat) / along_len[1] * grid[1]), 0, grid[1] - 1).astype(np.int64)
        out[key] = rows
        out[key + "_cell"] = np.where(keep, ix * grid[1] + iy, -1)
    return out


def frame_headings(scene: Scene, scale: float, cfg: WindowConfig) -> np.ndarray:
    """(N, T) heading of each agent's own frame: direction of motion over the last `heading_window_s`,
    or the scene's heading where the agent moved less than `min_motion` metres (stationary) or has no past."""
    back = max(1, int(round(cfg.heading_window_s / scene.dt)))
    prev = np.roll(scene.xy, back, axis=1)
    prev_valid = np.roll(scene.valid, back, axis=1)
    prev_valid[:, :back] = False
    disp = (scene.xy - prev) / scale
    moving = scene.valid & prev_valid & (np.hypot(disp[..., 0], disp[..., 1]) > cfg.min_motion)
    return np.where(moving, np.arctan2(disp[..., 1], disp[..., 0]), scene.heading).astype(np.float32)


def frame_concentration(xy: np.ndarray, heading: np.ndarray, valid: np.ndarray, cols: np.ndarray,
                        box: tuple[float, float], max_pairs: int = 1 << 21) -> np.ndarray:
    """`concentration` at frames `cols` of a scene, frames in chunks rather than one by one.

    xy (N, T, 2) metres, heading, valid (N, T), cols (C,) -> (N, T) float32 counts (zero off `cols` and where
    invalid). Each frame's present agents are packed first and padded to the chunk's largest count.
    """
    n, t = valid.shape
    out = np.zeros((n, t), np.float32)
    cols = np.asarray(cols, np.int64)
    if cols.size == 0 or n == 0:
        return out
    counts = valid[:, cols].sum(0)
    # Present rows first in each column (stable: by row), so a frame's agents are rows[:count].
    order = np.argsort(~valid[:, cols], axis=0, kind="stable")
    start = 0
    while start < cols.size:
        stop = start + 1  # grow the chunk while its padded pair count stays under max_pairs
        while stop < cols.size and counts[start:stop + 1].max() ** 2 * (stop + 1 - start) <= max_pairs:
            stop += 1
        k = int(counts[start:stop].max())
        if k:
            c = cols[start:stop]
            rows = order[:k, start:stop]  # (k, C)
            ok = np.arange(k)[:, None] < counts[start:stop]
            p, h = xy[rows, c], heading[rows, c]  # (k, C, 2), (k, C)
            cos, sin = np.cos(h)[:, None], np.sin(h)[:, None]
            dx, dy = p[None, :, :, 0] - p[:, None, :, 0], p[None, :, :, 1] - p[:, None, :, 1]  # (k, k, C): j - i
            along = cos * dx + sin * dy  # as `to_local`, without stacking the pair
            inside = (along > 0) & (along <= box[0]) & (np.abs(-sin * dx + cos * dy) <= box[1] / 2) & ok[None]
            cc = np.broadcast_to(c, rows.shape)
            out[rows[ok], cc[ok]] = inside.sum(1)[ok]
        start = stop
    return out


def scene_arrays(scene: Scene, cfg: WindowConfig, frames: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-agent-frame arrays of one scene in metres: xy, vel (N, T, 2); heading, conc (N, T); valid (N, T);
    length, width, type (N,). Concentration is computed at `frames` columns only (all if None)."""
    scale = cfg.scale_for(scene)
    valid = scene.valid.copy()
    # Zero where invalid: whatever a scene holds there never reaches a feature, and the cache stores valid entries only.
    xy = np.where(valid[..., None], scene.xy / scale, 0).astype(np.float32)
    heading = np.where(valid, frame_headings(scene, scale, cfg), 0).astype(np.float32)
    cols = np.arange(scene.num_frames) if frames is None else np.asarray(frames, np.int64)
    conc = frame_concentration(xy, heading, valid, cols, cfg.concentration_box)
    return {"xy": xy, "vel": np.where(valid[..., None], scene.velocity / scale, 0).astype(np.float32),
            "heading": heading, "conc": conc, "valid": valid, "length": (scene.length / scale).astype(np.float32),
            "width": (scene.width / scale).astype(np.float32), "type": scene.agent_type.astype(np.int8)}


def index_dtype(size: int) -> type:
    """The smallest signed integer type that holds -1 .. size (compact indices)."""
    for dt in (np.int8, np.int16, np.int32):
        if size < np.iinfo(dt).max:
            return dt
    return np.int64


# ---------------------------------------------------------------------------- the store
@dataclasses.dataclass
class Batch:
    """One batch of B samples, each in its target agent's frame (metres).

    hist (B, H, D), nbr (B, Kn, H, D), hz (B, Kh, H, D): Omega of target, neighbours, horizon agents.
    nbr_cell (B, Kn), hz_cell (B, Kh) int64: grid cell of each neighbour, -1 where none.
    fut (B, F, 2), fut_valid (B, F): ground-truth future (zeros / False at inference).
    origin (B, 2), heading (B,): the target frames in world metres, to map forecasts back.
    agent_type (B,) int8.
    """

    hist: np.ndarray
    nbr: np.ndarray
    nbr_cell: np.ndarray
    hz: np.ndarray
    hz_cell: np.ndarray
    fut: np.ndarray
    fut_valid: np.ndarray
    origin: np.ndarray
    heading: np.ndarray
    agent_type: np.ndarray

    def __len__(self) -> int:
        return int(self.hist.shape[0])

    def tensors(self) -> dict[str, Any]:
        """torch tensors of the model inputs and targets, sharing the arrays' memory (imports torch lazily).

        hist, nbr and hz may be strided views of one array (`FeatureStore.batch`): models gather or reshape them.
        """
        import torch

        return {k: torch.from_numpy(getattr(self, k))
                for k in ("hist", "nbr", "nbr_cell", "hz", "hz_cell", "fut", "fut_valid")}


AF_KEYS = ("xy", "vel", "heading", "conc", "valid", "length", "width", "type")
INDEX_KEYS = ("sample_scene", "target", "nbr", "nbr_cell", "hz", "hz_cell")


class FeatureStore:
    """All agent-frames of some scenes as flat arrays, plus the sample index (one sample = target at a "now").

    Agent-frame a of scene s, row r, column t sits at base[s] + r * T_s + t, so the same agent `k` steps
    back is `a - k * step`. Arrays (A = all agent-frames): xy, vel (A, 2) float32; heading, conc (A,) float32;
    valid (A,) bool; length, width (A,) float32; type (A,) int8. Index (S samples): sample_scene (S,) int32,
    target (S,) agent-frame at now, nbr / hz (S, K) agent-frames of the selected agents at now (-1 none),
    nbr_cell / hz_cell (S, K) grid cells (-1 none); indices in the smallest integer type that holds them
    (`index_dtype`). shapes (scenes, 2): (agents, frames) of each scene, the layout of the agent-frames.
    """

    def __init__(self, arrays: dict[str, np.ndarray], cfg: WindowConfig, step: int, frames: tuple[int, int],
                 scene_ids: list[str], has_future: bool = True, shapes: np.ndarray | None = None):
        self.a = arrays
        self.cfg = cfg
        self.step = step
        self.H, self.F = frames
        self.scene_ids = scene_ids
        self.has_future = has_future
        self.shapes = shapes

    # -------------------------------------------------------------- building
    @staticmethod
    def build(scenes: Sequence[Scene], scene_ids: Sequence[str], cfg: WindowConfig,
              targets: Sequence[np.ndarray] | None = None, require_future: bool = True,
              progress: bool = False) -> FeatureStore:
        """Flatten scenes and index every window.

        Training/evaluation (targets None, require_future True): a sample is an agent valid over its whole
        window (history and future) at a "now" every `cfg.stride` frames.
        Inference (targets given per scene, require_future False): one "now" at the last column,
        the given rows. A target recorded for less than the window (just appeared, or the first seconds of a
        closed-loop episode) gets the rest extrapolated back at constant velocity (`fill_history`): the models
        are trained on full histories only. Other agents' missing steps have present = 0, as in training.
        """
        if not scenes:
            raise UserError("no scenes to build windows from")
        dt = scenes[0].dt
        step = cfg.step(dt)
        H, F = cfg.frames(dt)
        parts: dict[str, list[np.ndarray]] = {k: [] for k in (*AF_KEYS, *INDEX_KEYS)}
        shapes = []
        base = 0
        it = enumerate(scenes)
        if progress:
            from tqdm import tqdm

            it = tqdm(it, total=len(scenes), desc="windows", unit="scene", leave=False)
        for s, scene in it:
            if abs(scene.dt - dt) > 1e-9:
                raise UserError(f"scene {scene_ids[s]!r} has dt {scene.dt:g} s, the others {dt:g} s")
            pad = (H - 1) * step
            if not require_future:  # pad history on the left, as far as needed, so partial histories index safely
                scene = (fill_history(scene, pad + 1, targets[s]) if targets is not None
                         else _pad_left(scene, pad + 1 - scene.num_frames))
            n, t = scene.valid.shape
            shapes.append((n, t))
            if targets is None:
                nows = np.arange(pad, t - F * step, max(1, cfg.stride))
                offs = np.arange(-(H - 1), F + 1) * step
                ok = scene.valid[:, nows[:, None] + offs[None, :]].all(-1) if nows.size else np.zeros((n, 0), bool)
                tgt_rows = [np.flatnonzero(ok[:, w]) for w in range(nows.size)]
            else:
                nows = np.array([t - 1])
                tgt_rows = [np.asarray(targets[s], np.int64)]
            keep = [w for w in range(nows.size) if tgt_rows[w].size]
            hist_cols = np.unique((nows[keep, None] + np.arange(-(H - 1), 1) * step).ravel()) if keep else None
            arr = scene_arrays(scene, cfg, frames=hist_cols if hist_cols is not None else np.zeros(0, int))
            for k in AF_KEYS:
                v = arr[k]
                if v.ndim == 1:
                    v = np.repeat(v[:, None], t, 1)
                parts[k].append(v.reshape(n * t, *v.shape[2:]))
            for w in keep:  # one "now" at a time: all its targets' neighbourhoods at once
                now, rows = int(nows[w]), tgt_rows[w]
                present = np.flatnonzero(scene.valid[:, now])
                sel = select_neighbours(arr["xy"][present, now], arr["heading"][present, now], cfg)
                local = np.searchsorted(present, rows)
                for key in ("nbr", "hz"):
                    r = sel[key][local]
                    parts[key].append(np.where(r >= 0, base + present[np.maximum(r, 0)] * t + now, -1))
                    parts[key + "_cell"].append(sel[key + "_cell"][local])
                parts["target"].append(base + rows * t + now)
                parts["sample_scene"].append(np.full(rows.size, s, np.int32))
            base += n * t
        arrays = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
        af_type = index_dtype(base)
        for key, k, grid in (("nbr", cfg.max_neighbours, cfg.neighbour_grid),
                             ("hz", cfg.max_horizon, cfg.horizon_grid)):
            arrays[key] = arrays[key].reshape(-1, k).astype(af_type)
            arrays[key + "_cell"] = arrays[key + "_cell"].reshape(-1, k).astype(index_dtype(grid[0] * grid[1]))
        arrays["target"] = arrays["target"].astype(af_type)
        arrays["sample_scene"] = arrays["sample_scene"].astype(np.int32)
        return FeatureStore(arrays, cfg, step, (H, F), list(scene_ids), has_future=require_future,
                            shapes=np.array(shapes, np.int64).reshape(-1, 2))

    # -------------------------------------------------------------- access
    def __len__(self) -> int:
        return int(self.a["target"].shape[0])

    def samples_of(self, scene_ids: Sequence[str]) -> np.ndarray:
        """Sample indices whose scene is in scene_ids."""
        wanted = np.isin(np.asarray(self.scene_ids), list(scene_ids))
        return np.flatnonzero(wanted[self.a["sample_scene"]])

    def _table(self) -> np.ndarray:
        """(A, 8) float32 per agent-frame: x, y, vx, vy, concentration, length, width, type; one gather per
        slot instead of seven (np.take on rows of one table is many times faster than fancy indexing)."""
        if getattr(self, "_af_table", None) is None:
            a = self.a
            self._af_table = np.concatenate([a["xy"], a["vel"], a["conc"][:, None], a["length"][:, None],
                                             a["width"][:, None], a["type"][:, None]], 1, dtype=np.float32)
        return self._af_table

    def batch(self, idx: np.ndarray) -> Batch:
        """Gather samples idx (B,) into a Batch: target, neighbours and horizon agents in one pass of numpy
        gathers (no per-sample Python)."""
        a, step, H, F = self.a, self.step, self.H, self.F
        idx = np.asarray(idx)
        kn, nt = a["nbr"].shape[1], len(AgentType)
        tgt = np.take(a["target"], idx).astype(np.int64)
        slots = np.concatenate([tgt[:, None], np.take(a["nbr"], idx, 0), np.take(a["hz"], idx, 0)], 1)  # (B, S)
        af = np.maximum(slots, 0).astype(np.int64)[..., None] + np.arange(-(H - 1), 1) * step  # (B, S, H)
        present = (slots >= 0)[..., None] & np.take(a["valid"], af)
        g = np.take(self._table(), af, 0)  # (B, S, H, 8)
        origin, heading = np.take(a["xy"], tgt, 0), np.take(a["heading"], tgt)
        c, s = np.cos(heading)[:, None, None], np.sin(heading)[:, None, None]
        dx, dy = g[..., 0] - origin[:, None, None, 0], g[..., 1] - origin[:, None, None, 1]
        om = np.empty((*af.shape, NUM_FEATURES), np.float32)  # Omega of every slot; slot 0 is the target
        om[..., 0] = c * dx + s * dy
        om[..., 1] = -s * dx + c * dy
        om[..., 2] = c * g[..., 2] + s * g[..., 3]
        om[..., 3] = -s * g[..., 2] + c * g[..., 3]
        om[..., 4:7] = g[..., 4:7]
        om[..., 7:7 + nt] = g[..., 7:8] == np.arange(nt, dtype=np.float32)
        om[..., _PRESENT] = 1.0
        om[..., _PRESENT + 1:_PRESENT + 3] = om[..., 2:4] - om[:, :1, :, 2:4]  # relative to the target's velocity
        dx, dy = om[..., 0] - om[:, :1, :, 0], om[..., 1] - om[:, :1, :, 1]
        om[..., _PRESENT + 3] = np.sqrt(dx * dx + dy * dy)  # distance to the target at the same step
        om *= present[..., None]
        fut_idx = np.minimum(tgt[:, None] + np.arange(1, F + 1) * step, len(a["valid"]) - 1)
        # Inference stores end at "now": their future would index the next agent's row.
        fut_valid = np.take(a["valid"], fut_idx) & self.has_future
        fut = to_local(np.take(a["xy"], fut_idx, 0), origin[:, None], heading[:, None]) * fut_valid[..., None]
        return Batch(hist=om[:, 0], nbr=om[:, 1:1 + kn], nbr_cell=np.take(a["nbr_cell"], idx, 0).astype(np.int64),
                     hz=om[:, 1 + kn:], hz_cell=np.take(a["hz_cell"], idx, 0).astype(np.int64),
                     fut=fut.astype(np.float32), fut_valid=fut_valid, origin=origin, heading=heading,
                     agent_type=np.take(a["type"], tgt))


def _pad_left(scene: Scene, pad: int) -> Scene:
    """`pad` invalid columns before column 0 (histories shorter than the window index safely)."""
    if pad <= 0:
        return scene
    p2 = ((0, 0), (pad, 0))
    return scene.replace(xy=np.pad(scene.xy, (*p2, (0, 0))), heading=np.pad(scene.heading, p2),
                         speed=np.pad(scene.speed, p2), valid=np.pad(scene.valid, p2),
                         extra={k: np.pad(v, p2) for k, v in scene.extra.items()}, frame0=scene.frame0 - pad)


def fill_history(scene: Scene, frames: int, rows: np.ndarray) -> Scene:
    """`scene` with the agents `rows` (present at the last column) present in all of its last `frames` columns:
    the columns before an agent's first recorded frame (left-padded where the scene is shorter) extrapolated
    back at its velocity between its first two recorded frames (at its recorded speed along its recorded
    heading where it has only one), its heading, speed and extras held at the first frame's. Gaps after the
    first frame stay gaps.

    scene: (N, T) agents x frames; frames: columns wanted; rows (M,) int -> Scene (N, max(T, frames)). Other
    agents (the targets' neighbours) stay as recorded, as in training.
    """
    scene = _pad_left(scene, frames - scene.num_frames)
    t = scene.num_frames
    cols = np.arange(t)
    valid = scene.valid
    first = np.where(valid.any(1), valid.argmax(1), t)  # (N,) first recorded column, t where none
    rows = np.asarray(rows, np.int64)
    rows = rows[valid[rows, -1] & (first[rows] > t - frames)]
    if rows.size == 0:
        return scene
    f = first[rows]
    later = valid[rows] & (cols[None] > f[:, None])
    two = later.any(1)
    s = np.where(two, later.argmax(1), f)  # second recorded column (the first where there is none)
    xy = scene.xy[rows]
    r = np.arange(rows.size)
    # Seen once: its recorded speed along its heading (a standstill would be forecast for a car that just came in).
    h, v = scene.heading[rows, f], scene.speed[rows, f] * scene.dt
    once = np.where(np.isfinite(h * v)[:, None], heading_velocity(v, h), 0.0)
    vel = np.where(two[:, None], (xy[r, s] - xy[r, f]) / np.maximum(s - f, 1)[:, None], once)  # per column
    fill = (cols[None] < f[:, None]) & (cols[None] >= t - frames)  # (R, T)
    back = (f[:, None] - cols[None]).astype(np.float32)

    def hold(a: np.ndarray) -> np.ndarray:  # (N, T): the targets' filled columns at their first frame's value
        a = a.copy()
        a[rows] = np.where(fill, a[rows, f][:, None], a[rows])
        return a

    out_xy, out_valid = scene.xy.copy(), valid.copy()
    out_xy[rows] = np.where(fill[..., None], xy[r, f][:, None] - back[..., None] * vel[:, None], xy)
    out_valid[rows] |= fill
    return scene.replace(xy=out_xy, valid=out_valid, heading=hold(scene.heading), speed=hold(scene.speed),
                         extra={k: hold(v) for k, v in scene.extra.items()})
