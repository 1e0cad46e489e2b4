"""The project's own data set format: a folder of Parquet shards (one per scene) and `_manifest.json`.

One row per valid agent-frame, sorted by (frame, agent row)::

    scene_id, frame, t, agent_id, agent_type, x, y, heading, speed, length, width, is_ego, <extra...>

`agent_type` is a dictionary-encoded lowercase string (dictionary = every `AgentType` label, in code
order, so pandas reads it as a categorical whose codes are the `AgentType` values); one float32
column per `Scene.extra` key follows. Everything else a `Scene` holds (dt, frame0, frame count, the
agent table in row order, ego, meta with events, seed, road geometry) sits in the shard's Parquet
key-value metadata under `simharness` as JSON, so a shard is self-describing. Entries of invalid
agent-frames are not stored: they read back as zeros (what simulators and `scene_from_frames` emit).

Every file is written under a temporary name and renamed when complete; identical input gives
identical bytes (no timestamps, hostnames or wall times anywhere). Files that are not shards start with
`_` (`_manifest.json`, `_runs.jsonl`, `_lock`) or `.tmp-`, names pandas, pyarrow, polars and DuckDB skip,
so any of them opens the folder as one table. The manifest lists each shard's size and sha256: opening a
data set checks both, so a shard damaged, truncated or replaced after it was written is named, never used.
Shards also vouch for themselves: every Parquet page carries a CRC32 checksum, the `simharness` metadata
is checked against its schema and size bounds before anything is allocated, and the rows must fit it, so a
writer judges a shard damaged by its own bytes (`shard_damage`), never by a manifest that may be the one
that changed. Column units and meanings travel as Arrow field metadata (`unit`, `description`); the
schema is documented column by column in docs/dataset.md.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import json
import math
import os
import platform
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from simharness.errors import UserError
from simharness.io.folders import TMP_PREFIX, check_writable, clean_stale_temp, dir_mode, file_mode
from simharness.scene import LABELS, AgentType, Scene, agent_types_from_labels
from simharness.sim.base import RoadGeometry

SCHEMA_VERSION: int = 1
MANIFEST = "_manifest.json"
LEGACY_MANIFEST = "manifest.json"  # written before 0.1.1 (a name readers took for a shard); still read
META_KEY = b"simharness"
BASE_COLUMNS = ("scene_id", "frame", "t", "agent_id", "agent_type", "x", "y", "heading", "speed",
                "length", "width", "is_ego")
_TYPE_DICT = pa.array(LABELS, pa.string())
MAX_CELLS = 100_000_000  # agents x frames of one shard: each dense float32 array of it is at most 400 MB
MAX_MANIFEST_BYTES = 512 << 20  # about 1.5 million scenes' entries
MAX_META_BYTES = 256 << 20  # a shard's `simharness` metadata (road geometry, events) is far smaller
T_DECIMALS = 9  # `t` = frame x dt rounded to the nanosecond: 0.6, not 0.6000000000000001
# (unit, description) of every base column, stored as Arrow field metadata; docs/dataset.md says the same.
COLUMN_DOCS: dict[str, tuple[str, str]] = {
    "scene_id": ("", "the scene this row belongs to: the shard's file name without .parquet"),
    "frame": ("frame", "frame index in the scene's recording; the first recorded frame is frame0"),
    "t": ("s", "time of the frame: frame x dt, rounded to 1 ns"),
    "agent_id": ("", "agent identifier, stable within the scene"),
    "agent_type": ("", "car, bus, truck, rickshaw, motorcycle, scooter, bicycle, pedestrian or other"),
    "x": ("m", "footprint centre, world frame"),
    "y": ("m", "footprint centre, world frame; +y is 90 degrees counter-clockwise from +x"),
    "heading": ("rad", "direction of the agent's body, counter-clockwise from +x"),
    "speed": ("m/s", "speed along the heading"),
    "length": ("m", "footprint length (one value per agent)"),
    "width": ("m", "footprint width (one value per agent)"),
    "is_ego": ("", "true on the rows of the scene's ego agent (closed-loop episodes), else false"),
}
EXTRA_DOCS: dict[str, tuple[str, str]] = {
    "lateral_offset": ("m", "distance from the carriageway's centre line, positive to the left; on highway-env "
                            "data it equals y"),
    "sim_heading": ("rad", "the simulator's own box heading (SUMO aligns it with the lane), the one its collision "
                           "check uses"),
}


# ---------------------------------------------------------------------- small file helpers
def _json_default(obj: Any) -> Any:
    """numpy scalars/arrays and tuples in meta become plain JSON."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    raise TypeError(f"meta value of type {type(obj).__name__} is not JSON-serialisable")


def dumps(obj: Any, indent: int | None = None) -> str:
    """Canonical JSON (sorted keys) so equal content gives equal bytes."""
    return json.dumps(obj, sort_keys=True, indent=indent, default=_json_default, allow_nan=True,
                      separators=(",", ": ") if indent else (",", ":"))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary sibling, fsync, rename: readers never see half a file."""
    path = Path(path)
    # The pid in the name tells a later run whether the writer is gone (`folders.clean_stale_temp`).
    fd, tmp = tempfile.mkstemp(prefix=f"{TMP_PREFIX}{path.name}.{os.getpid()}.", dir=path.parent)
    try:
        os.fchmod(fd, file_mode())  # mkstemp makes 0600; data sets are meant to be shared (0644 by umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise



def atomic_write_text(path: Path, text: str) -> None:
    """UTF-8 text through `atomic_write_bytes`."""
    atomic_write_bytes(path, text.encode("utf-8"))

@contextlib.contextmanager
def atomic_folder(out: Path, overwrite: bool = False) -> Iterator[Path]:
    """Build a folder under a temporary sibling name, yielded; rename it to `out` when the block completes.

    An existing non-empty `out` is refused (UserError) unless `overwrite`, and then replaced only once the
    new folder is complete; on any error the temporary folder is removed and `out` is left as it was.
    """
    out = Path(out)
    check_writable(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:
        raise UserError(f"{out}: exists and is not empty; choose another output folder or remove it")
    try:
        out.parent.mkdir(parents=True, exist_ok=True, mode=dir_mode())
        clean_stale_siblings(out)
        # The pid in the name tells the next run whether the writer is gone (its folder then removed).
        tmp = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}{out.name}.{os.getpid()}.", dir=out.parent))
        os.chmod(tmp, dir_mode())  # mkdtemp makes 0700
    except OSError as e:
        raise UserError(f"{out}: cannot create the output folder ({e.strerror or e})") from None
    try:
        yield tmp
        if out.exists():
            old = out.with_name(f"{TMP_PREFIX}{out.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

def clean_stale_siblings(out: Path) -> list[Path]:
    """Remove what killed writers of `out` left beside it: `.tmp-{out.name}.{pid}.*` of dead processes (a killed
    `import` or `export`) and `.tmp-{out.name}.old` (a replaced folder not yet deleted). Returns them."""
    out = Path(out)
    removed = clean_stale_temp(out.parent, f"{TMP_PREFIX}{out.name}.")
    old = out.with_name(f"{TMP_PREFIX}{out.name}.old")
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old, ignore_errors=True)
        removed.append(old)
    return removed


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def software_versions() -> dict[str, str]:
    """Versions of what shapes the data (python, numpy, pyarrow, sumo, highway-env, simharness)."""
    out = {"python": platform.python_version(), "numpy": np.__version__, "pyarrow": pa.__version__}
    for key, dist in (("sumo", "eclipse-sumo"), ("libsumo", "libsumo"), ("highway-env", "highway-env"),
                      ("simharness", "simharness")):
        try:
            out[key] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[key] = "not installed"
    return out


# ---------------------------------------------------------------------- one shard
def scene_table(scene: Scene, scene_id: str) -> pa.Table:
    """The rows of one shard: valid agent-frames sorted by (frame, agent row), metadata attached."""
    clash = sorted(set(scene.extra) & set(BASE_COLUMNS))
    if clash:
        raise ValueError(f"Scene.extra key {clash[0]!r} clashes with a base column name")
    # (frame, row) order: transpose so that frames vary slowest.
    col, row = np.nonzero(scene.valid.T)
    n = row.size
    frame = (scene.frame0 + col).astype(np.int32)
    types = pa.DictionaryArray.from_arrays(pa.array(scene.agent_type[row].astype(np.int8), pa.int8()),
                                           _TYPE_DICT)
    columns: dict[str, pa.Array] = {
        "scene_id": pa.DictionaryArray.from_arrays(pa.array(np.zeros(n, np.int8)), pa.array([scene_id])),
        "frame": pa.array(frame),
        "t": pa.array(np.round(frame.astype(np.float64) * scene.dt, T_DECIMALS)),
        "agent_id": pa.array(scene.agent_id[row].astype(object), pa.string()),
        "agent_type": types,
        "x": pa.array(scene.xy[row, col, 0]),
        "y": pa.array(scene.xy[row, col, 1]),
        "heading": pa.array(scene.heading[row, col]),
        "speed": pa.array(scene.speed[row, col]),
        "length": pa.array(scene.length[row]),
        "width": pa.array(scene.width[row]),
        "is_ego": pa.array(row == scene.ego if scene.ego >= 0 else np.zeros(n, bool)),
    }
    for key in sorted(scene.extra):
        columns[key] = pa.array(scene.extra[key][row, col].astype(np.float32))
    info = {
        "schema_version": SCHEMA_VERSION,
        "scene_id": scene_id,
        "dt": scene.dt,
        "frame0": scene.frame0,
        "num_frames": scene.num_frames,
        "ego": scene.ego,
        "agents": {  # row order and per-agent constants, incl. agents without a valid frame
            "agent_id": scene.agent_id.tolist(),
            "agent_type": [AgentType(int(t)).label for t in scene.agent_type],
            "length": scene.length.astype(np.float64).tolist(),
            "width": scene.width.astype(np.float64).tolist(),
        },
        "extra": sorted(scene.extra),
        "meta": scene.meta,
    }
    docs = {**COLUMN_DOCS, **EXTRA_DOCS}

    def unit(name: str) -> str:  # lengths in the scene's own unit (px for unscaled video imports)
        u = docs.get(name, ("", ""))[0]
        return {"m": scene.units, "m/s": f"{scene.units}/s"}.get(u, u)

    fields = [pa.field(name, arr.type, metadata={"unit": unit(name),
                                                 "description": docs.get(name, ("", "extra per agent-frame value"))[1]})
              for name, arr in columns.items()]
    schema = pa.schema(fields, metadata={META_KEY: dumps(info).encode()})
    return pa.Table.from_arrays(list(columns.values()), schema=schema)


def write_scene(scene: Scene, path: Path, scene_id: str) -> int:
    """Write one scene as one Parquet shard, atomically (temporary name, then rename). Returns rows."""
    path = Path(path)
    table = scene_table(scene, scene_id)
    sink = pa.BufferOutputStream()
    # zstd for size; no statistics-dependent wall clock anywhere, so bytes depend on content only.
    # Page checksums (CRC32): a shard shows damage by its own bytes, whatever a manifest says.
    pq.write_table(table, sink, compression="zstd", row_group_size=1 << 20, use_dictionary=["scene_id",
                   "agent_type", "agent_id"], write_page_checksum=True)
    atomic_write_bytes(path, sink.getvalue().to_pybytes())
    return table.num_rows


def _shard_info(path: Path) -> dict[str, Any]:
    """The shard's `simharness` metadata, checked against its schema and bounds (`check_shard_info`)."""
    try:
        kv = pq.read_schema(path).metadata or {}
    except (OSError, pa.ArrowException) as e:
        raise UserError(f"{path}: corrupt or unreadable Parquet shard ({_short(e)})") from None
    if META_KEY not in kv:
        raise UserError(f"{path}: not a simharness shard (no '{META_KEY.decode()}' key-value metadata)")
    if len(kv[META_KEY]) > MAX_META_BYTES:
        raise UserError(f"{path}: shard metadata '{META_KEY.decode()}' is {len(kv[META_KEY]):,} bytes; at most "
                        f"{MAX_META_BYTES:,} expected")
    try:
        info = json.loads(kv[META_KEY])
    except (ValueError, RecursionError) as e:
        raise UserError(f"{path}: shard metadata '{META_KEY.decode()}' is not valid JSON ({_short(e)})") from None
    return check_shard_info(info, path)


def _bad(path: Path, field: str, expected: str, got: Any) -> UserError:
    text = repr(got)
    return UserError(f"{path}: field {field!r}: expected {expected}, got {text[:60]}{'...' if len(text) > 60 else ''}")


def _int(d: dict[str, Any], key: str, path: Path, lo: int, hi: int, field: str | None = None) -> int:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise _bad(path, field or key, f"a whole number in {lo}..{hi}", v)
    return v


def _number(v: Any, path: Path, field: str, lo: float, hi: float, lo_open: bool = False) -> float:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and lo <= v <= hi \
        and not (lo_open and v == lo)
    if not ok:
        raise _bad(path, field, f"a finite number in {'(' if lo_open else '['}{lo:g}, {hi:g}]", v)
    return float(v)


def check_shard_info(info: Any, path: Path) -> dict[str, Any]:
    """`info` if it is a shard's metadata of the expected schema within the size bounds, else one UserError
    naming the field: checked before any array of its sizes is allocated."""
    if not isinstance(info, dict):
        raise _bad(path, META_KEY.decode(), "a JSON object", type(info).__name__)
    if info.get("schema_version") != SCHEMA_VERSION:
        raise UserError(f"{path}: shard schema version {info.get('schema_version')!r}; this simharness reads "
                        f"version {SCHEMA_VERSION}")
    if not isinstance(info.get("scene_id"), str):
        raise _bad(path, "scene_id", "a string", info.get("scene_id"))
    _number(info.get("dt"), path, "dt", 0.0, 3600.0, lo_open=True)
    _int(info, "frame0", path, 0, 2**31 - 1)
    t = _int(info, "num_frames", path, 0, MAX_CELLS)
    agents = info.get("agents")
    if not isinstance(agents, dict):
        raise _bad(path, "agents", "an object of agent_id, agent_type, length, width lists", agents)
    for key in ("agent_id", "agent_type", "length", "width"):
        if not isinstance(agents.get(key), list):
            raise _bad(path, f"agents.{key}", "a list", agents.get(key))
    n = len(agents["agent_id"])
    if n * max(t, 1) > MAX_CELLS:
        raise UserError(f"{path}: fields 'agents' x 'num_frames' = {n:,} x {t:,}; at most {MAX_CELLS:,} "
                        "agent-frames per shard")
    for key in ("agent_type", "length", "width"):
        if len(agents[key]) != n:
            raise _bad(path, f"agents.{key}", f"{n} entries (one per agent_id)", f"{len(agents[key])} entries")
    if not all(isinstance(a, str) for a in agents["agent_id"]) or len(set(agents["agent_id"])) != n:
        raise _bad(path, "agents.agent_id", "distinct strings", "other values")
    unknown = next((a for a in agents["agent_type"] if a not in LABELS), None)
    if unknown is not None:
        raise _bad(path, "agents.agent_type", f"labels among {', '.join(LABELS)}", unknown)
    for key in ("length", "width"):
        for v in agents[key]:
            _number(v, path, f"agents.{key}", 0.0, 1e4)
    _int(info, "ego", path, -1, n - 1)
    extra = info.get("extra")
    if not isinstance(extra, list) or not all(isinstance(k, str) and k not in BASE_COLUMNS for k in extra):
        raise _bad(path, "extra", "a list of column names", extra)
    meta = info.get("meta")
    if not isinstance(meta, dict):
        raise _bad(path, "meta", "a JSON object", meta)
    if not isinstance(meta.get("events", []), list) or not all(isinstance(e, dict) for e in meta.get("events", [])):
        raise _bad(path, "meta.events", "a list of event objects", meta.get("events"))
    if not isinstance(meta.get("units", "m"), str):
        raise _bad(path, "meta.units", "a string such as m or px", meta.get("units"))
    if "units_per_m" in meta:
        _number(meta["units_per_m"], path, "meta.units_per_m", 0.0, 1e6, lo_open=True)
    check_road(meta.get("road"), path)
    return info


def _short(e: BaseException) -> str:
    return str(e).strip().splitlines()[0][:200] if str(e).strip() else type(e).__name__


def read_scene(path: Path) -> Scene:
    """One shard back to the `Scene` that was written (invalid entries as zeros). UserError if corrupt."""
    path = Path(path)
    info = _shard_info(path)
    try:
        table = pq.read_table(path, page_checksum_verification=True)
    except (OSError, pa.ArrowException) as e:
        raise UserError(f"{path}: corrupt or unreadable Parquet shard ({_short(e)})") from None
    agents = info["agents"]
    ids = np.asarray(agents["agent_id"], dtype=object).astype(str)
    n, t = len(ids), int(info["num_frames"])
    try:
        missing = [c for c in ("agent_id", "frame", "x", "y", "heading", "speed", *info["extra"])
                   if c not in table.column_names]
        if missing:
            raise ValueError(f"column {missing[0]!r} missing")
        for c in ("x", "y", "heading", "speed"):
            if not np.isfinite(table.column(c).to_numpy()).all():
                raise ValueError(f"column {c!r} holds NaN or infinity")
        row_ids = table.column("agent_id").to_numpy(zero_copy_only=False).astype(str)
        if len(row_ids) and n == 0:
            raise ValueError("rows but an empty agent table")
        order = np.argsort(ids, kind="stable")
        row = order[np.clip(np.searchsorted(ids[order], row_ids), 0, max(n - 1, 0))]
        col = table.column("frame").to_numpy().astype(np.int64) - int(info["frame0"])
        if len(row_ids) and ((ids[row] != row_ids).any() or col.min() < 0 or col.max() >= t):
            raise ValueError("rows do not match the shard's agent table")
        if len(row_ids) and np.unique(row * max(t, 1) + col).size != len(row_ids):
            raise ValueError("two rows for one agent-frame")

        def dense(name: str) -> np.ndarray:
            out = np.zeros((n, t), np.float32)
            out[row, col] = table.column(name).to_numpy()
            return out

        valid = np.zeros((n, t), bool)
        valid[row, col] = True
        xy = np.stack([dense("x"), dense("y")], -1)
        return Scene(
            xy=xy, heading=dense("heading"), speed=dense("speed"), valid=valid, agent_id=ids,
            agent_type=agent_types_from_labels(agents["agent_type"]) if n else np.zeros(0, np.int8),
            length=np.asarray(agents["length"], np.float32), width=np.asarray(agents["width"], np.float32),
            dt=float(info["dt"]), ego=int(info["ego"]), frame0=int(info["frame0"]),
            extra={k: dense(k) for k in info["extra"]}, meta=info["meta"],
        )
    except (KeyError, IndexError, ValueError, TypeError, pa.ArrowException) as e:
        raise UserError(f"{path}: corrupt shard ({_short(e)})") from None


def shard_damage(path: Path) -> str | None:
    """Why the shard's own bytes show it damaged (unreadable footer, a page failing its checksum, metadata
    outside its schema, rows that do not fit it, a scene id other than its file name), or None if intact.

    Reads the whole shard. A shard is removed only on this word, never because a manifest disagrees.
    """
    path = Path(path)
    try:
        scene = read_scene(path)
    except UserError as e:
        text = str(e)
        return text[len(str(path)) + 2:] if text.startswith(f"{path}: ") else text
    if scene.meta.get("scene_id", path.stem) != path.stem or _shard_info(path)["scene_id"] != path.stem:
        return f"holds scene {_shard_info(path)['scene_id']!r}, not the one its file name says"
    return None


# ---------------------------------------------------------------------- manifest
def shard_name(scene_id: str) -> str:
    return f"{scene_id}.parquet"


def shard_entry(path: Path, scene: Scene, scene_id: str, rows: int) -> dict[str, Any]:
    """One manifest line for a written shard."""
    return {"scene_id": scene_id, "file": Path(path).name, "rows": int(rows), "agents": scene.num_agents,
            "frames": scene.num_frames, "bytes": Path(path).stat().st_size, "sha256": file_sha256(path)}


def describe_shard(path: Path) -> dict[str, Any]:
    """Manifest entry of a shard already on disk (from its footer, no row reading), plus its `meta`.

    Returns {scene_id, file, rows, agents, frames, bytes, sha256, meta}; UserError if unreadable.
    """
    path = Path(path)
    info = _shard_info(path)
    try:
        rows = pq.read_metadata(path).num_rows
    except (OSError, pa.ArrowException) as e:
        raise UserError(f"{path}: corrupt or unreadable Parquet shard ({_short(e)})") from None
    return {"scene_id": info["scene_id"], "file": path.name, "rows": int(rows),
            "agents": len(info["agents"]["agent_id"]), "frames": int(info["num_frames"]),
            "bytes": path.stat().st_size, "sha256": file_sha256(path), "meta": info["meta"]}


def content_hash(entries: Iterable[dict[str, Any]]) -> str:
    """sha256 over the shards' (file, sha256) pairs in scene-id order: the data set's identity."""
    scenes = sorted(entries, key=lambda e: e["scene_id"])
    return hashlib.sha256("".join(f"{e['file']}:{e.get('sha256', '')}\n" for e in scenes).encode()).hexdigest()


def shard_problem(path: Path, entry: dict[str, Any], hash_it: bool = True) -> str | None:
    """Why the shard at `path` is not the one `entry` lists (missing, size, sha256), or None if it is."""
    try:
        size = Path(path).stat().st_size
    except FileNotFoundError:
        return "missing"
    if "bytes" in entry and size != entry["bytes"]:
        return f"{size} bytes, the manifest lists {entry['bytes']} (truncated or replaced)"
    if hash_it and "sha256" in entry and file_sha256(path) != entry["sha256"]:
        return "content differs from the sha256 the manifest lists (changed after it was written)"
    return None


def build_manifest(entries: Iterable[dict[str, Any]], info: dict[str, Any]) -> dict[str, Any]:
    """Manifest content from shard entries (sorted by scene id) and the caller's info."""
    scenes = sorted(entries, key=lambda e: e["scene_id"])
    content = content_hash(scenes)
    return {
        "format": "simharness-dataset",
        "schema_version": SCHEMA_VERSION,
        "columns": list(BASE_COLUMNS),
        "info": info,
        "versions": software_versions(),
        "num_scenes": len(scenes),
        "rows": int(sum(e["rows"] for e in scenes)),
        "content_hash": content,
        "scenes": scenes,
    }


def write_manifest(out: Path, manifest: dict[str, Any]) -> Path:
    """`_manifest.json` (strict JSON: a NaN anywhere is a bug upstream); an old `manifest.json` goes."""
    path = Path(out) / MANIFEST
    try:
        text = json.dumps(manifest, sort_keys=True, indent=1, default=_json_default, allow_nan=False)
    except ValueError:
        raise UserError(f"{path}: refusing to write a manifest holding NaN or infinity (a non-finite setting "
                        "got through)") from None
    atomic_write_bytes(path, (text + "\n").encode())
    with contextlib.suppress(FileNotFoundError):
        (Path(out) / LEGACY_MANIFEST).unlink()
    return path


def manifest_path(folder: Path) -> Path:
    """The folder's manifest file: `_manifest.json`, else a legacy `manifest.json` (which may not exist)."""
    new = Path(folder) / MANIFEST
    old = Path(folder) / LEGACY_MANIFEST
    return old if not new.is_file() and old.is_file() else new


def clean_temp_files(out: Path) -> list[Path]:
    """Remove leftovers of interrupted writes (`.tmp-*` files, and folders, in `out`; links are removed, never
    followed); returns what was removed. Only for a folder whose writer lock is held."""
    stale = sorted(Path(out).glob(TMP_PREFIX + "*"))
    for p in stale:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
            continue
        with contextlib.suppress(OSError):
            p.unlink()
    return stale


def write_dataset(scenes: Iterable[Scene], out: Path, info: dict[str, Any], overwrite: bool = False) -> Path:
    """Shards and manifest in one go (importers, closed-loop episodes); returns the folder.

    A scene's id is `meta["scene_id"]` when given, else `scene-{i:06d}`. The folder is built under a
    temporary sibling name and renamed when complete. An existing non-empty `out` is refused unless
    `overwrite` (then replaced only once the new one is complete).
    """
    out = Path(out)
    with atomic_folder(out, overwrite) as tmp:
        entries, seen = [], set()
        for i, scene in enumerate(scenes):
            scene_id = str(scene.meta.get("scene_id", f"scene-{i:06d}"))
            if scene_id in seen:
                raise ValueError(f"duplicate scene id {scene_id!r}")
            seen.add(scene_id)
            path = tmp / shard_name(scene_id)
            rows = write_scene(scene, path, scene_id)
            entries.append(shard_entry(path, scene, scene_id, rows))
        write_manifest(tmp, build_manifest(entries, info))
    return out


def read_manifest(path: Path) -> dict[str, Any]:
    """`_manifest.json` (or a legacy `manifest.json`) of a data set folder; UserError one-liners for the usual
    mistakes."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: data set folder not found")
    if not path.is_dir():
        raise UserError(f"{path}: expected a data set folder (with {MANIFEST}), got a file")
    mpath = manifest_path(path)
    if not mpath.is_file():
        raise UserError(f"{mpath}: missing; expected a simharness data set folder (run `simharness generate` "
                        f"or `simharness import` to make one)")
    size = mpath.stat().st_size
    if size > MAX_MANIFEST_BYTES:
        raise UserError(f"{mpath}: {size:,} bytes; a manifest is at most {MAX_MANIFEST_BYTES:,}")
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise UserError(f"{mpath}: not valid JSON ({_short(e)})") from None
    return check_manifest(manifest, mpath)


def check_manifest(manifest: Any, mpath: Path) -> dict[str, Any]:
    """`manifest` if it has the schema `build_manifest` writes, else one UserError naming the field."""
    if not isinstance(manifest, dict) or manifest.get("format") != "simharness-dataset":
        raise UserError(f"{mpath}: not a simharness data set manifest (key 'format' != 'simharness-dataset')")
    if manifest.get("schema_version") != SCHEMA_VERSION:
        raise UserError(f"{mpath}: key 'schema_version' is {manifest.get('schema_version')!r}; this simharness "
                        f"reads version {SCHEMA_VERSION}")
    for key in ("info", "versions"):
        if not isinstance(manifest.get(key, {}), dict):
            raise _bad(mpath, key, "a JSON object", manifest.get(key))
    for key in ("num_scenes", "rows"):
        if key in manifest:
            _int(manifest, key, mpath, 0, 2**63 - 1)
    scenes = manifest.get("scenes", [])
    if not isinstance(scenes, list) or not all(isinstance(e, dict) and isinstance(e.get("file"), str)
                                               and isinstance(e.get("scene_id"), str) for e in scenes):
        raise UserError(f"{mpath}: key 'scenes' must be a list of {{scene_id, file, ...}} entries")
    bad = [e["file"] for e in scenes if Path(e["file"]).name != e["file"] or not e["file"].endswith(".parquet")
           or e["file"].startswith((".", "_"))]
    if bad:
        raise UserError(f"{mpath}: shard {bad[0]!r} is not a .parquet file name inside the folder")
    files = [e["file"] for e in scenes]
    if len(set(files)) != len(files) or len({e["scene_id"] for e in scenes}) != len(scenes):
        raise UserError(f"{mpath}: key 'scenes' lists a shard or scene id twice")
    for i, e in enumerate(scenes):
        for key, hi in (("rows", 2**63 - 1), ("agents", MAX_CELLS), ("frames", MAX_CELLS), ("bytes", 2**63 - 1)):
            if key in e or key == "rows":
                _int(e, key, mpath, 0, hi, field=f"scenes[{i}].{key}")
        sha = e.get("sha256")
        if "sha256" in e and not (isinstance(sha, str) and len(sha) == 64
                                  and all(c in "0123456789abcdef" for c in sha)):
            raise _bad(mpath, f"scenes[{i}].sha256", "64 lowercase hex digits", sha)
    return manifest


MAX_ROAD_POINTS = 1_000_000  # vertices of all road polygons of a data set


def check_road(road: Any, path: Path) -> Any:
    """`road` if it is road geometry as `RoadGeometry.to_dict` writes it ({drivable, sidewalks, markings}: lists
    of polygons of finite [x, y] points, at most MAX_ROAD_POINTS in all), else one UserError naming the field."""
    if not road:
        return road
    if not isinstance(road, dict) or set(road) - {"drivable", "sidewalks", "markings"}:
        raise _bad(path, "road", "an object of drivable, sidewalks, markings polygons", road)
    total = 0
    for key, polygons in road.items():
        if not isinstance(polygons, list):
            raise _bad(path, f"road.{key}", "a list of polygons", polygons)
        for i, poly in enumerate(polygons):
            ok = isinstance(poly, list) and len(poly) >= 1 and all(
                isinstance(pt, list) and len(pt) == 2 and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in pt)
                for pt in poly)
            if not ok:
                raise _bad(path, f"road.{key}[{i}]", "a list of finite [x, y] points", poly)
            total += len(poly)
    if total > MAX_ROAD_POINTS:
        raise UserError(f"{path}: field 'road': {total:,} points; at most {MAX_ROAD_POINTS:,}")
    return road


# ---------------------------------------------------------------------- read side
class Dataset:
    """A data set folder, read lazily: `len`, iteration and `scene(i or id)` give `Scene`s.

    Opening checks the manifest and every listed shard against it (presence, size and sha256: about 1 ms
    per MB), so a missing, truncated or replaced shard is named up front, and refuses a folder holding
    shards the manifest does not list (an interrupted `generate`: rerunning it lists them). `content_hash`
    is computed from the shards as found, so caches keyed on it follow the content.
    """

    def __init__(self, path: Path, verify: bool = True) -> None:
        self.path = Path(path)
        self.manifest: dict[str, Any] = read_manifest(self.path)
        mname = manifest_path(self.path).name
        entries = self.manifest.get("scenes", [])
        self.scene_ids: list[str] = [e["scene_id"] for e in entries]
        self.shard_paths: list[Path] = [self.path / e["file"] for e in entries]
        for entry, shard in zip(entries, self.shard_paths, strict=True):
            problem = shard_problem(shard, entry, hash_it=verify)
            if problem == "missing":
                raise UserError(f"{shard}: shard listed in {mname} is missing")
            if problem and shard_damage(shard) is None:  # the entry is what changed
                raise UserError(f"{shard}: {problem.split(' (')[0]}, yet the shard reads intact (page checksums, "
                                f"metadata, rows): the {mname} entry is wrong; rerun the `simharness generate` "
                                "command that made the data set to repair it, or re-import it")
            if problem:
                raise UserError(f"{shard}: damaged shard: {problem}; regenerate or re-import the data set")
        listed = {e["file"] for e in entries}
        unlisted = sorted(p.name for p in self.path.glob("*.parquet") if p.name not in listed)
        if unlisted:
            raise UserError(f"{self.path / unlisted[0]}: shard not listed in {mname} ({len(unlisted)} such); the "
                            "writer was interrupted: rerun the same `simharness generate` command to finish it")
        self.content_hash: str = content_hash(entries)
        self._road: RoadGeometry | None = None
        self._road_read = False

    @property
    def info(self) -> dict[str, Any]:
        """What the writer recorded (source, scenario spec, seeds, config hash...)."""
        return self.manifest.get("info", {})

    @property
    def road(self) -> RoadGeometry | None:
        """Road geometry from the first shard's meta (shared by all scenes of a scenario), or None."""
        if not self._road_read:
            self._road_read = True
            road, where = self.info.get("road"), manifest_path(self.path)
            if road is None and self.shard_paths:
                road, where = _shard_info(self.shard_paths[0])["meta"].get("road"), self.shard_paths[0]
            self._road = RoadGeometry.from_dict(check_road(road, where)) if road else None
        return self._road

    def __len__(self) -> int:
        return len(self.scene_ids)

    def __iter__(self) -> Iterator[Scene]:
        for p in self.shard_paths:
            yield read_scene(p)

    def scene(self, key: int | str) -> Scene:
        """Scene by position or by scene id."""
        if isinstance(key, str):
            if key not in self.scene_ids:
                raise UserError(f"{self.path}: no scene {key!r} (it holds {len(self)} scenes)")
            key = self.scene_ids.index(key)
        if not -len(self) <= key < len(self):
            raise UserError(f"{self.path}: scene index {key} out of range (it holds {len(self)} scenes)")
        return read_scene(self.shard_paths[key])

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r}, scenes={len(self)}, rows={self.manifest.get('rows')})"
