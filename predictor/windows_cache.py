"""The windows cache: a `FeatureStore` on disk in compact form, keyed so that a stale or damaged file is never used.

Where: $SIMHARNESS_CACHE_DIR, else $XDG_CACHE_HOME/simharness, else ~/.cache/simharness (sub-folder windows/),
never inside the data set folder, which stays exactly what its manifest lists (its content hash, its shard
list, `simharness generate` resuming into it) and may be read-only.

Key: sha256 of the data set's content hash, the window config, FEATURES_VERSION and the source of
predictor/features.py. Each file repeats its key and is checked when read: another key, a damaged zip or
arrays that do not fit together mean a rebuild. Files unused for 30 days are removed when a new one is written.

Compact form (about 4x smaller than the arrays in memory):
- agent-frame arrays only where valid (xy, vel, heading float32, concentration uint16), valid as packed bits;
- length, width and type once per agent, not per frame;
- the index as agent rows within the scene at the target's "now" (int16 below 32k agents a scene), grid
  cells int8, the target agent-frame in the smallest type that holds it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from predictor import features
from predictor.features import FEATURES_VERSION, FeatureStore, WindowConfig, index_dtype
from simharness.errors import UserError
from simharness.scene import Scene

CACHE_FORMAT = 2


def default_cache_dir() -> Path:
    """$SIMHARNESS_CACHE_DIR, else $XDG_CACHE_HOME/simharness, else ~/.cache/simharness; + /windows."""
    root = os.environ.get("SIMHARNESS_CACHE_DIR")
    if not root:
        root = str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "simharness")
    return Path(root) / "windows"


def cache_key(data_key: str, cfg: WindowConfig) -> dict[str, Any]:
    """What a cached store depends on: the data, the windows and the code that builds them."""
    code = hashlib.sha256(Path(features.__file__).read_bytes()).hexdigest()[:16]
    key = {"format": CACHE_FORMAT, "features_version": FEATURES_VERSION, "features_code": code,
           "data": str(data_key), "window": cfg.to_dict()}
    return json.loads(json.dumps(key))  # as read back from the file (tuples become lists)


def _layout(shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(base (scenes,), frames of each agent (agents,), first agent-frame of each agent (agents,))."""
    n, t = shapes[:, 0], shapes[:, 1]
    base = np.concatenate([[0], np.cumsum(n * t)[:-1]]).astype(np.int64)
    agent_t = np.repeat(t, n)
    first = np.repeat(base, n) + (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)) * agent_t
    return base, agent_t, first


def save_store(store: FeatureStore, path: Path, key: dict[str, Any] | None = None) -> None:
    """The store's compact form -> path (.npz, deflated: 16x smaller, read as fast), atomically."""
    a, shapes = store.a, store.shapes
    if shapes is None:
        raise ValueError("a store without scene shapes (built by an older version) cannot be saved")
    base, agent_t, first = _layout(shapes)
    valid = a["valid"].astype(bool)
    has_frames = agent_t > 0
    per_agent = {}
    for k, dtype in (("length", np.float32), ("width", np.float32), ("type", np.int8)):
        v = np.zeros(len(first), dtype)
        v[has_frames] = a[k][first[has_frames]]
        per_agent[k + "_agent"] = v
    s = a["sample_scene"].astype(np.int64)
    rows_type = index_dtype(int(shapes[:, 0].max(initial=0)))
    index = {}
    for k in ("nbr", "hz"):
        af = a[k].astype(np.int64)
        rows = (af - base[s][:, None]) // np.maximum(shapes[s, 1], 1)[:, None]
        index[k + "_row"] = np.where(af >= 0, rows, -1).astype(rows_type)
    meta = {"key": key, "cfg": store.cfg.to_dict(), "step": store.step, "H": store.H, "F": store.F,
            "scene_ids": store.scene_ids, "has_future": store.has_future}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}.npz")
    try:
        np.savez_compressed(tmp, meta=np.array(json.dumps(meta)), shapes=shapes.astype(np.int64),
                 valid_bits=np.packbits(valid), xy=a["xy"][valid], vel=a["vel"][valid], heading=a["heading"][valid],
                 conc=np.minimum(a["conc"][valid], np.iinfo(np.uint16).max).astype(np.uint16), **per_agent,
                 sample_scene=a["sample_scene"].astype(index_dtype(len(shapes))),
                 target=a["target"], nbr_cell=a["nbr_cell"], hz_cell=a["hz_cell"], **index)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _check(ok: bool, what: str, path: Path) -> None:
    if not ok:
        raise UserError(f"{path}: damaged windows cache ({what}); delete it and it will be rebuilt")


def load_store(path: Path, key: dict[str, Any] | None = None) -> FeatureStore:
    """A store written by `save_store`; with `key`, only if it was saved under that key. UserError otherwise."""
    try:
        return _load(path, key)
    except UserError:
        raise
    except Exception as e:  # a missing array, a wrong dtype or shape: the file is not what save_store wrote
        raise UserError(f"{path}: damaged windows cache ({type(e).__name__}: {e}); delete it and it will be "
                        "rebuilt") from None


def _load(path: Path, key: dict[str, Any] | None) -> FeatureStore:
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        meta = json.loads(str(d.pop("meta")))
    except Exception as e:  # zip, CRC, JSON and numpy errors all mean the same: unusable
        raise UserError(f"{path}: unreadable windows cache ({type(e).__name__}); it will be rebuilt") from None
    _check(meta.get("key") == key if key is not None else True, "made for other data, windows or code", path)
    shapes = d["shapes"].astype(np.int64).reshape(-1, 2)
    _check(len(shapes) == len(meta["scene_ids"]) and (shapes >= 0).all(), "scene shapes", path)
    base, agent_t, first = _layout(shapes)
    total = int((shapes[:, 0] * shapes[:, 1]).sum())
    _check(d["valid_bits"].size == (total + 7) // 8, "valid mask size", path)
    valid = np.unpackbits(d["valid_bits"], count=total).astype(bool)
    nv = int(valid.sum())
    _check(d["xy"].shape == (nv, 2) and d["vel"].shape == (nv, 2) and d["heading"].shape == (nv,)
           and d["conc"].shape == (nv,), "agent-frame arrays", path)
    _check(all(d[k + "_agent"].shape == agent_t.shape for k in ("length", "width", "type")), "agent arrays", path)
    a: dict[str, np.ndarray] = {"valid": valid}
    for k, width in (("xy", 2), ("vel", 2), ("heading", 0), ("conc", 0)):
        full = np.zeros((total, width) if width else total, np.float32)
        full[valid] = d[k]
        a[k] = full
    for k in ("length", "width", "type"):
        a[k] = np.repeat(d[k + "_agent"], agent_t)
    cfg = WindowConfig.from_dict(meta["cfg"])
    s = d["sample_scene"].astype(np.int64)
    target = d["target"]
    _check(target.ndim == 1 and s.shape == target.shape, "sample index", path)
    if target.size:
        _check(0 <= s.min() and s.max() < len(shapes), "sample scenes", path)
        _check(0 <= target.min() and target.max() < total and valid[target].all(), "targets", path)
    now = (target.astype(np.int64) - base[s]) % np.maximum(shapes[s, 1], 1)
    af_type = index_dtype(total)
    for k, slots, grid in (("nbr", cfg.max_neighbours, cfg.neighbour_grid), ("hz", cfg.max_horizon, cfg.horizon_grid)):
        rows, cells = d[k + "_row"].astype(np.int64), d[k + "_cell"]
        _check(rows.shape == (len(target), slots) and cells.shape == rows.shape, f"{k} index shape", path)
        _check(((rows >= -1) & (rows < shapes[s, 0][:, None])).all(), f"{k} rows", path)
        _check(((cells >= -1) & (cells < grid[0] * grid[1])).all() and ((cells >= 0) == (rows >= 0)).all(),
               f"{k} cells", path)
        a[k] = np.where(rows >= 0, base[s][:, None] + rows * shapes[s, 1][:, None] + now[:, None], -1).astype(af_type)
        a[k + "_cell"] = cells
    a["target"] = target.astype(af_type)
    a["sample_scene"] = s.astype(np.int32)
    return FeatureStore(a, cfg, int(meta["step"]), (int(meta["H"]), int(meta["F"])), list(meta["scene_ids"]),
                        has_future=bool(meta["has_future"]), shapes=shapes)


def cached_store(cache_dir: Path, data_key: str, cfg: WindowConfig,
                 scenes_fn: Callable[[], tuple[list[Scene], list[str]]], progress: bool = True) -> FeatureStore:
    """The store of (data_key, cfg) from cache_dir, or built with scenes_fn() and saved there (when writable)."""
    key = cache_key(data_key, cfg)
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
    path = Path(cache_dir) / f"windows-{digest}.npz"
    if path.is_file():
        try:
            store = load_store(path, key)
            with contextlib.suppress(OSError):
                os.utime(path)  # last used: what pruning goes by
            return store
        except UserError:  # a stale or damaged cache is rebuilt, never trusted
            path.unlink(missing_ok=True)
    scenes, ids = scenes_fn()
    store = FeatureStore.build(scenes, ids, cfg, progress=progress)
    try:
        save_store(store, path, key)
        prune(Path(cache_dir))
    except OSError:  # a read-only cache folder: work without the cache
        pass
    return store


def prune(cache_dir: Path, max_age_days: float = 30.0) -> list[Path]:
    """Remove cached windows unused for `max_age_days` (those of edited code or deleted data sets); -> removed."""
    cutoff = time.time() - max_age_days * 86400
    old = [p for p in Path(cache_dir).glob("windows-*.npz") if p.stat().st_mtime < cutoff]
    for p in old:
        p.unlink(missing_ok=True)
    return old
