"""The TraPHic authors' TrackNPred layout (`.txt` rows, or `.npy` arrays; pickled ones only when allowed) ->
Scenes."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.io.importers.source import (
    PathLike,
    check_file,
    integral,
    read_numeric_table,
    scene_from_rows,
    source_meta,
    where_lines,
)
from simharness.io.importers.traf import TRAF_DT
from simharness.scene import AgentType, Scene

TRACKNPRED_DT = TRAF_DT
PICKLE_REFUSAL = ("{path}: a pickled NumPy object array: loading it can run arbitrary code, so it is refused; "
                  "import the .txt beside it, or pass --allow-pickle if you trust this file")


def _check_npy_header(path: Path) -> None:
    """UserError unless the .npy header's shape and dtype fit the bytes that follow it: checked before NumPy
    allocates the array a crafted header declares (e.g. 34 TiB for a small file)."""
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(f)
            data_bytes = path.stat().st_size - f.tell()
    except (ValueError, OSError, SyntaxError, TypeError) as e:
        raise UserError(f"{path}: not a readable .npy file ({str(e).splitlines()[0][:120] if str(e) else e})") \
            from None
    if dtype.hasobject:
        return  # a pickle: refused below unless the user trusts it
    need = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if len(shape) > 2 or need > data_bytes:
        raise UserError(f"{path}: header declares an array of shape {shape} and dtype {dtype} ({need:,} bytes); "
                        f"the file holds {data_bytes:,} bytes of data: truncated or crafted")


def _tracknpred_rows(path: Path, allow_pickle: bool) -> tuple[np.ndarray, np.ndarray]:
    """(values (R, 5): dataset, id, frame, x, y; line or row numbers (R,)) from any TrackNPred file."""
    if path.suffix == ".npy":
        _check_npy_header(path)
        try:
            data = np.load(path, allow_pickle=False)
        except ValueError as e:
            if "allow_pickle" not in str(e):
                raise UserError(f"{path}: not a readable .npy file ({e})") from None
            if not allow_pickle:
                raise UserError(PICKLE_REFUSAL.format(path=path)) from None
            data = np.load(path, allow_pickle=True)  # the user explicitly trusts this file
        except OSError as e:
            raise UserError(f"{path}: not a readable .npy file ({e})") from None
        traj = data[0] if data.dtype == object else data  # [traj (N x 47), tracks dict] or a plain array
        traj = np.asarray(traj, dtype=np.float64)
        if traj.ndim != 2 or traj.shape[1] < 5:
            raise UserError(f"{path}: expected rows of dataset id, agent id, frame, x, y (...); got shape {traj.shape}")
        bad = np.flatnonzero(~np.isfinite(traj[:, :5]).all(axis=1))
        if bad.size:
            raise UserError(f"{path}:row {bad[0]}: dataset id, agent id, frame, x, y must be finite")
        return traj[:, :5], np.arange(len(traj))
    with open(path, encoding="utf-8", errors="replace") as f:
        head = f.readline()
    if "," in head:  # formatted_hypo.txt: dsId,id,frame,x,y
        vals, lines = read_numeric_table(path, (5,), "dsId,id,frame,x,y", sep=",")
        return vals, lines
    vals, lines = read_numeric_table(path, (5,), "frame id x y dataset")  # TrainSet.txt
    return vals[:, [4, 1, 0, 2, 3]], lines


def _export_info(path: Path) -> dict[str, Any]:
    """Units and dt per dsId when `path` sits in a `simharness export tracknpred` folder, else {}."""
    info = path.resolve().parent.parent / "simharness_export.json"
    if not info.is_file():
        return {}
    try:
        return dict(json.loads(info.read_text())["scenes"])
    except (ValueError, KeyError, TypeError):
        raise UserError(f"{info}: not a valid simharness export description") from None


def import_tracknpred(paths: Sequence[PathLike], allow_pickle: bool = False, dt: float = TRACKNPRED_DT) -> list[
        Scene]:
    """The TraPHic authors' layouts, one scene per (file, dataset id), pixels.

    Accepts `TrainSet.txt`-style files (`frame id x y dataset`, tab separated), `formatted_hypo.txt`
    (`dsId,id,frame,x,y`, what `simharness export tracknpred` writes), and their `.npy` files; those
    are pickles and are refused unless `allow_pickle` (the user's explicit `--allow-pickle`). The
    layout holds no class and no frame rate: agents are OTHER and `dt` defaults to TRAF's 20 fps
    (units and dt are read back from `simharness_export.json` when the file comes from our export).
    """
    scenes = []
    for p in paths:
        path = check_file(p)
        vals, lines = _tracknpred_rows(path, allow_pickle)
        where = where_lines(path, lines, "row " if path.suffix == ".npy" else "")
        ds = integral(vals[:, 0], where, "dataset id")
        ids = integral(vals[:, 1], where, "agent id")
        frame = integral(vals[:, 2], where, "frame")
        exported = _export_info(path)
        for d in np.unique(ds):
            rows = np.flatnonzero(ds == d)
            scene_id = f"{path.stem}-ds{int(d)}"
            known = exported.get(str(int(d)), {})
            note = "from simharness_export.json" if known else "not in the layout; TRAF's 20 fps assumed"
            meta = source_meta(path, "tracknpred", scene_id, units=known.get("units", "px"), dataset_id=int(d),
                                frame_rate_note=note, exported_scene=known.get("scene_id", ""))
            scenes.append(scene_from_rows(
                frame[rows], ids[rows].astype(str), vals[rows, 3:5], dt=float(known.get("dt", dt)),
                agent_type=np.full(rows.size, AgentType.OTHER, np.int8),
                where=where_lines(path, lines[rows], "row " if path.suffix == ".npy" else ""),
                meta=meta,
            ))
    return scenes
