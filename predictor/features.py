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
sample index are built once and cached (`FeatureStore.build`), so a training batch is a handful of
numpy gathers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.scene import AgentType, Scene

FEATURES_VERSION = 1
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
                        "meta['units_per_m']; give WindowConfig(length_scale=UNITS_PER_METRE) so that the "
                        "ellipses and grids have a size in its units")

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


def rotate_to_local(v: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Vectors into frames: v (..., 2), heading (...) -> (..., 2)."""
    c, s = np.cos(heading), np.sin(heading)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], -1)


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


def scene_arrays(scene: Scene, cfg: WindowConfig, frames: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-agent-frame arrays of one scene in metres: xy, vel (N, T, 2); heading, conc (N, T); valid (N, T);
    length, width, type (N,). Concentration is computed at `frames` columns only (all if None)."""
    scale = cfg.scale_for(scene)
    xy = (scene.xy / scale).astype(np.float32)
    heading = frame_headings(scene, scale, cfg)
    conc = np.zeros(scene.valid.shape, np.float32)
    cols = range(scene.num_frames) if frames is None else frames
    for t in cols:  # per frame; all agents of the frame at once
        rows = np.flatnonzero(scene.valid[:, t])
        if rows.size:
            conc[rows, t] = concentration(xy[rows, t], heading[rows, t], cfg.concentration_box)
    return {"xy": xy, "vel": (scene.velocity / scale).astype(np.float32), "heading": heading, "conc": conc,
            "valid": scene.valid.copy(), "length": scene.length / scale, "width": scene.width / scale,
            "type": scene.agent_type.astype(np.int8)}


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
        """torch tensors of the model inputs and targets (imports torch lazily)."""
        import torch

        return {k: torch.from_numpy(np.ascontiguousarray(getattr(self, k)))
                for k in ("hist", "nbr", "nbr_cell", "hz", "hz_cell", "fut", "fut_valid")}


_AF_KEYS = ("xy", "vel", "heading", "conc", "valid", "length", "width", "type")
_INDEX_KEYS = ("sample_scene", "target", "nbr", "nbr_cell", "hz", "hz_cell")


class FeatureStore:
    """All agent-frames of some scenes as flat arrays, plus the sample index (one sample = target at a "now").

    Agent-frame a of scene s, row r, column t sits at base[s] + r * T_s + t, so the same agent `k` steps
    back is `a - k * step`. Arrays (A = all agent-frames): xy, vel (A, 2); heading, conc (A,); valid (A,);
    length, width, type (A,). Index (S samples): sample_scene (S,), target (S,) agent-frame at now,
    nbr / hz (S, K) agent-frames of the selected agents at now (-1 none), nbr_cell / hz_cell (S, K).
    """

    def __init__(self, arrays: dict[str, np.ndarray], cfg: WindowConfig, step: int, frames: tuple[int, int],
                 scene_ids: list[str], has_future: bool = True):
        self.a = arrays
        self.cfg = cfg
        self.step = step
        self.H, self.F = frames
        self.scene_ids = scene_ids
        self.has_future = has_future

    # -------------------------------------------------------------- building
    @staticmethod
    def build(scenes: Sequence[Scene], scene_ids: Sequence[str], cfg: WindowConfig,
              targets: Sequence[np.ndarray] | None = None, require_future: bool = True,
              progress: bool = False) -> FeatureStore:
        """Flatten scenes and index every window.

        Training/evaluation (targets None, require_future True): a sample is an agent valid over its whole
        window (history and future) at a "now" every `cfg.stride` frames.
        Inference (targets given per scene, require_future False): one "now" at the last column,
        the given rows; histories may be partial (missing steps have present = 0).
        """
        if not scenes:
            raise UserError("no scenes to build windows from")
        dt = scenes[0].dt
        step = cfg.step(dt)
        H, F = cfg.frames(dt)
        parts: dict[str, list[np.ndarray]] = {k: [] for k in (*_AF_KEYS, *_INDEX_KEYS)}
        base = 0
        it = enumerate(scenes)
        if progress:
            from tqdm import tqdm

            it = tqdm(it, total=len(scenes), desc="windows", unit="scene", leave=False)
        for s, scene in it:
            if abs(scene.dt - dt) > 1e-9:
                raise UserError(f"scene {scene_ids[s]!r} has dt {scene.dt:g} s, the others {dt:g} s")
            pad = (H - 1) * step
            if not require_future:  # pad history on the left so partial histories index safely
                scene = _pad_left(scene, pad)
            n, t = scene.valid.shape
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
            for k in _AF_KEYS:
                v = arr[k]
                if v.ndim == 1:
                    v = np.repeat(v[:, None], t, 1)
                parts[k].append(v.reshape(n * t, *v.shape[2:]))
            for w in keep:
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
        kn, kh = cfg.max_neighbours, cfg.max_horizon
        for key, k, dtype in (("nbr", kn, np.int64), ("nbr_cell", kn, np.int64), ("hz", kh, np.int64),
                              ("hz_cell", kh, np.int64)):
            arrays[key] = arrays[key].reshape(-1, k).astype(dtype)
        arrays["target"] = arrays["target"].astype(np.int64)
        arrays["sample_scene"] = arrays["sample_scene"].astype(np.int32)
        return FeatureStore(arrays, cfg, step, (H, F), list(scene_ids), has_future=require_future)

    # -------------------------------------------------------------- caching
    def save(self, path: Path) -> None:
        """Atomic .npz write (tmp + rename)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + f".tmp{os.getpid()}.npz")
        np.savez(tmp, **self.a, meta=np.array(json.dumps({
            "cfg": self.cfg.to_dict(), "step": self.step, "H": self.H, "F": self.F, "scene_ids": self.scene_ids})))
        os.replace(tmp, path)

    @staticmethod
    def load(path: Path) -> FeatureStore:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if k != "meta"}
            meta = json.loads(str(z["meta"]))
        return FeatureStore(arrays, WindowConfig.from_dict(meta["cfg"]), meta["step"], (meta["H"], meta["F"]),
                            meta["scene_ids"])

    @staticmethod
    def cached(cache_dir: Path, data_key: str, cfg: WindowConfig, scenes_fn: Any,
               progress: bool = True) -> FeatureStore:
        """Load the store for (data_key, cfg) from cache_dir, or build it with scenes_fn() -> (scenes, ids) and save."""
        key = hashlib.sha256(json.dumps([FEATURES_VERSION, data_key, cfg.to_dict()], sort_keys=True).encode())
        path = Path(cache_dir) / f"windows-{key.hexdigest()[:16]}.npz"
        if path.exists():
            try:
                return FeatureStore.load(path)
            except Exception:  # a stale or damaged cache is rebuilt, never trusted
                path.unlink(missing_ok=True)
        scenes, ids = scenes_fn()
        store = FeatureStore.build(scenes, ids, cfg, progress=progress)
        try:
            store.save(path)
        except OSError:  # a read-only data folder: work without the cache
            pass
        return store

    # -------------------------------------------------------------- access
    def __len__(self) -> int:
        return int(self.a["target"].shape[0])

    def samples_of(self, scene_ids: Sequence[str]) -> np.ndarray:
        """Sample indices whose scene is in scene_ids."""
        wanted = np.isin(np.asarray(self.scene_ids), list(scene_ids))
        return np.flatnonzero(wanted[self.a["sample_scene"]])

    def batch(self, idx: np.ndarray) -> Batch:
        """Gather samples idx (B,) into a Batch (vectorised; no per-sample Python)."""
        a, step, H, F = self.a, self.step, self.H, self.F
        tgt = self.a["target"][idx]
        hist_idx = tgt[:, None] + np.arange(-(H - 1), 1) * step  # (B, H)
        origin, heading = a["xy"][tgt], a["heading"][tgt]
        tvel = rotate_to_local(a["vel"][hist_idx], heading[:, None])  # (B, H, 2)
        txy = to_local(a["xy"][hist_idx], origin[:, None], heading[:, None])

        def omega(rows: np.ndarray) -> np.ndarray:  # rows (B, K) agent-frames at now, -1 none -> (B, K, H, D)
            have = rows >= 0
            af = np.maximum(rows, 0)[..., None] + np.arange(-(H - 1), 1) * step  # (B, K, H)
            present = have[..., None] & a["valid"][af]
            o, th = origin[:, None, None], heading[:, None, None]
            pos = to_local(a["xy"][af], o, th)
            vel = rotate_to_local(a["vel"][af], th)
            rel_v = vel - tvel[:, None]
            dist = np.linalg.norm(pos - txy[:, None], axis=-1)
            onehot = np.eye(len(AgentType), dtype=np.float32)[a["type"][af]]
            feats = np.concatenate([pos, vel, a["conc"][af][..., None], a["length"][af][..., None],
                                    a["width"][af][..., None], onehot, np.ones_like(dist)[..., None],
                                    rel_v, dist[..., None]], -1).astype(np.float32)
            return feats * present[..., None]

        hist = omega(tgt[:, None])[:, 0]
        fut_idx = np.minimum(tgt[:, None] + np.arange(1, F + 1) * step, len(a["valid"]) - 1)
        # Inference stores end at "now": their future would index the next agent's row.
        fut_valid = a["valid"][fut_idx] & self.has_future
        fut = to_local(a["xy"][fut_idx], origin[:, None], heading[:, None]) * fut_valid[..., None]
        return Batch(hist=hist, nbr=omega(a["nbr"][idx]), nbr_cell=a["nbr_cell"][idx], hz=omega(a["hz"][idx]),
                     hz_cell=a["hz_cell"][idx], fut=fut.astype(np.float32), fut_valid=fut_valid,
                     origin=origin, heading=heading, agent_type=a["type"][tgt])


def _pad_left(scene: Scene, pad: int) -> Scene:
    """`pad` invalid columns before column 0 (histories shorter than the window index safely)."""
    if pad <= 0:
        return scene
    p2 = ((0, 0), (pad, 0))
    return scene.replace(xy=np.pad(scene.xy, (*p2, (0, 0))), heading=np.pad(scene.heading, p2),
                         speed=np.pad(scene.speed, p2), valid=np.pad(scene.valid, p2),
                         extra={k: np.pad(v, p2) for k, v in scene.extra.items()}, frame0=scene.frame0 - pad)


def sample_history(scene: Scene, step: int, frames: int) -> Scene:
    """The last `frames` columns taken every `step` recorded frames, as a Scene with dt * step."""
    cols = scene.num_frames - 1 - np.arange(frames - 1, -1, -1) * step
    ok = cols >= 0
    c = np.maximum(cols, 0)
    valid = scene.valid[:, c] & ok
    return scene.replace(xy=scene.xy[:, c], heading=scene.heading[:, c], speed=scene.speed[:, c], valid=valid,
                         extra={k: v[:, c] for k, v in scene.extra.items()}, dt=scene.dt * step,
                         frame0=int(math.floor((scene.frame0 + cols[0]) / step)))
