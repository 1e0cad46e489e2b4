"""Reading a public data set's source files: file checks, numeric tables with one-line errors, rows -> Scene,
heading and speed from positions. Every importer module builds on these."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from simharness.errors import UserError
from simharness.scene import AgentType, Scene, stack_frames

PathLike = str | Path
# Bounds on what a source may hold, so a typo (frame 1e18, x 1e300) is one line, not a memory error or inf.
MAX_FRAME_NUMBER = 2**31  # |frame numbers, ids|
MAX_COLUMNS = 1_000_000  # frames per scene (11.6 days at 1 Hz)
MAX_CELLS = 200_000_000  # agents x frames of one scene, as dense arrays (~5 GB)
MAX_COORD = 1e7  # |x|, |y|, sizes, speeds in the source's units (float32 holds them to ~1 unit)


# ====================================================================== shared building blocks
def motion_from_positions(
    xy: np.ndarray, valid: np.ndarray, dt: float, min_speed: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Heading and speed from finite differences of positions.

    xy: (N, T, 2) positions (any unit); valid: (N, T) bool; dt: seconds per column.
    Returns heading (N, T) float32 radians CCW from +x and speed (N, T) float32 units/s.
    Central differences where both neighbours are valid, one-sided at track ends and beside gaps;
    an agent slower than `min_speed` keeps its last moving heading (else its next, else 0).
    """
    n, t = valid.shape
    step = np.zeros((n, max(t - 1, 0), 2), np.float64)
    ok = valid[:, 1:] & valid[:, :-1]  # (N, T-1) difference j joins columns j and j+1
    step[ok] = (xy[:, 1:][ok] - xy[:, :-1][ok]) / dt
    back = np.zeros((n, t, 2))
    fwd = np.zeros((n, t, 2))
    has_back = np.zeros((n, t), bool)
    has_fwd = np.zeros((n, t), bool)
    back[:, 1:], has_back[:, 1:] = step, ok
    fwd[:, :-1], has_fwd[:, :-1] = step, ok
    count = has_back.astype(np.float64) + has_fwd
    vel = (back + fwd) / np.maximum(count, 1)[..., None]
    speed = np.hypot(vel[..., 0], vel[..., 1])
    moving = valid & (count > 0) & (speed >= min_speed)
    raw = np.arctan2(vel[..., 1], vel[..., 0])
    cols = np.broadcast_to(np.arange(t), (n, t))
    # Forward then backward fill of the last moving heading along each row.
    last = np.maximum.accumulate(np.where(moving, cols, -1), axis=1)
    nxt = np.minimum.accumulate(np.where(moving, cols, t)[:, ::-1], axis=1)[:, ::-1]
    src = np.where(last >= 0, last, np.where(nxt < t, nxt, -1))
    rows = np.arange(n)[:, None]
    heading = np.where(src >= 0, raw[rows, np.clip(src, 0, t - 1)], 0.0)
    return (np.where(valid, heading, 0.0).astype(np.float32), np.where(valid, speed, 0.0).astype(np.float32))


def scene_from_rows(
    frame: np.ndarray,
    agent: np.ndarray,
    xy: np.ndarray,
    *,
    dt: float,
    agent_type: np.ndarray,
    meta: dict[str, Any],
    where: Callable[[int], str],
    frame_step: int = 1,
    heading: np.ndarray | None = None,
    speed: np.ndarray | None = None,
    size: np.ndarray | None = None,
    extra: dict[str, np.ndarray] | None = None,
    ego_id: str | None = None,
    duplicates: str = "error",
) -> Scene:
    """A `Scene` from long-format rows (one per agent-frame), via `stack_frames`.

    frame: (R,) int source frame numbers; agent: (R,) str ids; xy: (R, 2); agent_type: (R,) int8.
    heading, speed: (R,) or None (then from finite differences); size: (R, 2) length, width or None
    (then the type's default footprint in metres, or 0 for pixel data); extra: name -> (R,) values;
    where(i): "file:line" of row i.
    Columns are source frames first..last stepping by `frame_step`; frames absent from the source
    stay invalid columns. An agent's type, length and width are taken from its first row / median.
    duplicates: a second row of an agent in one frame is an error ("error"), or is dropped ("first")
    and counted in `meta["dropped_duplicates"]` (real annotations hold a few double boxes).
    """
    r = len(frame)
    if r == 0:
        raise UserError(f"{where(-1)}: no trajectory rows found")
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and 1e-4 <= dt <= 3600):
        raise UserError(f"{where(-1)}: frame interval {dt!r} s; expected a number in [0.0001, 3600]")
    _check_bounded(where, "x, y", xy)
    for name, arr in (("heading", heading), ("speed", speed), ("size", size), *(extra or {}).items()):
        if arr is not None:
            _check_bounded(where, name, arr)
    f0 = int(frame.min())
    rel = frame - f0
    off = np.flatnonzero(rel % frame_step)
    if off.size:
        i = int(off[0])
        raise UserError(f"{where(i)}: frame {int(frame[i])} is not on the {frame_step}-frame grid starting at {f0}")
    col = (rel // frame_step).astype(np.int64)
    num_frames = int(col.max()) + 1
    agent = np.asarray(agent).astype(str)
    if num_frames > MAX_COLUMNS:
        i = int(np.argmax(col))
        raise UserError(f"{where(i)}: frame {int(frame[i])} makes the scene {num_frames:,} frames long (from frame "
                        f"{f0}); at most {MAX_COLUMNS:,}: a typo in a frame number?")
    if num_frames * len(np.unique(agent)) > MAX_CELLS:
        raise UserError(f"{where(-1)}: {len(np.unique(agent)):,} agents x {num_frames:,} frames is too large for one "
                        f"scene (at most {MAX_CELLS:,}); split the file")
    # Duplicate (frame, agent) rows: report the second occurrence.
    key = pd.MultiIndex.from_arrays([col, agent])
    dup = np.flatnonzero(key.duplicated())
    if dup.size and duplicates == "error":
        i = int(dup[0])
        raise UserError(f"{where(i)}: agent {str(agent[i])!r} appears twice in frame {int(frame[i])}")
    meta = {**meta, "dropped_duplicates": int(dup.size)} if duplicates != "error" else meta
    if dup.size:
        keep = np.ones(r, bool)
        keep[dup] = False
        pick = (lambda a: None if a is None else np.asarray(a)[keep])  # noqa: E731
        frame, agent, xy, agent_type, heading, speed, size = map(pick, (frame, agent, xy, agent_type, heading,
                                                                        speed, size))
        extra = {k: v[keep] for k, v in (extra or {}).items()}
        col = col[keep]
        r = len(frame)
    order = np.argsort(col, kind="stable")
    bounds = np.searchsorted(col[order], np.arange(num_frames + 1))
    per_frame = [order[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    columns: dict[str, np.ndarray] = {"xy": xy, "type": np.asarray(agent_type, np.int8)}
    for name, arr in (("heading", heading), ("speed", speed)):
        if arr is not None:
            columns[name] = arr
    if size is not None:
        columns["size"] = size
    for name, arr in (extra or {}).items():
        columns["extra:" + name] = arr
    ids, valid, dense, first = stack_frames([agent[p] for p in per_frame],
                                            {k: [v[p] for p in per_frame] for k, v in columns.items()})
    rows = np.arange(len(ids))
    types = dense["type"][rows, first]
    if heading is None or speed is None:
        head_fd, speed_fd = motion_from_positions(dense["xy"], valid, dt)
    head = dense["heading"] if heading is not None else head_fd
    spd = dense["speed"] if speed is not None else speed_fd
    if size is not None:
        med = np.nanmedian(np.where(valid[..., None], dense["size"], np.nan), axis=1)
        length, width = med[:, 0], med[:, 1]
    elif meta.get("units", "m") == "m":
        foot = np.array([AgentType(int(k)).footprint for k in range(len(AgentType))], np.float32)
        length, width = foot[types, 0], foot[types, 1]
    else:  # metre footprints would be wrong in pixels: unknown sizes are 0
        length = width = np.zeros(len(ids), np.float32)
        meta = {**meta, "sizes": "unknown (0): the source gives none"}
    ego = -1
    if ego_id is not None and ego_id in set(ids.tolist()):
        ego = int(np.flatnonzero(ids == ego_id)[0])
    meta = {**meta, "source_frame_step": int(frame_step), "frame_rate_hz": round(1.0 / dt, 6)}
    meta.setdefault("units", "m")
    return Scene(
        xy=dense["xy"], heading=head, speed=spd, valid=valid, agent_id=ids, agent_type=types,
        length=length, width=width, dt=dt, ego=ego, frame0=f0 // frame_step,
        extra={k[6:]: dense[k] for k in dense if k.startswith("extra:")}, meta=meta,
    )


def sha256_file(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def source_meta(path: Path, fmt: str, scene_id: str, **more: Any) -> dict[str, Any]:
    return {"scene_id": scene_id, "scenario": scene_id, "format": fmt, "source": path.name,
            "source_sha256": sha256_file(path), **more}


def check_file(path: PathLike) -> Path:
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found" if not path.exists() else f"{path}: expected a file, got a folder")
    return path


def line_text(path: Path, lineno: int) -> str:
    with open(path, encoding="utf-8", errors="replace", newline="") as f:
        for i, line in enumerate(f, 1):
            if i == lineno:
                text = line.rstrip("\r\n")
                return text if len(text) <= 80 else text[:77] + "..."
    return ""


def _scan_bad_line(path: Path, counts: Sequence[int], sep: str | None, layout: str) -> UserError:
    """Error path only: the first non-blank line with a wrong field count or a non-number."""
    with open(path, encoding="utf-8", errors="replace", newline="") as f:
        for i, line in enumerate(f, 1):
            text = line.strip()
            if not text:
                continue
            fields = text.split(sep) if sep else text.split()
            if len(fields) not in counts:
                return UserError(f"{path}:{i}: expected {' or '.join(map(str, counts))} fields ({layout}), "
                                 f"got {len(fields)}: {line_text(path, i)!r}")
            for fld in fields:
                try:
                    if not math.isfinite(float(fld)):
                        raise ValueError
                except ValueError:
                    return UserError(f"{path}:{i}: expected numbers ({layout}), got {fld.strip()!r}")
    return UserError(f"{path}: cannot be read as {layout}")


def read_numeric_table(path: Path, counts: Sequence[int], layout: str, sep: str | None = None) -> tuple[
        np.ndarray, np.ndarray]:
    """A headerless numeric text table -> (values (R, C) float64, line numbers (R,) int).

    counts: allowed numbers of columns; sep: None for any whitespace, else the delimiter.
    Blank lines are skipped; anything else that is not a row of finite numbers is a UserError
    naming the file and line.
    """
    try:
        df = pd.read_csv(path, sep=sep or r"\s+", header=None, skip_blank_lines=False, dtype=str,
                         engine="c", keep_default_na=False, na_values=[""])
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError):
        raise _scan_bad_line(path, counts, sep, layout) from None
    except pd.errors.EmptyDataError:
        raise UserError(f"{path}: empty file; expected rows of {layout}") from None
    if df.shape[1] not in counts:
        raise _scan_bad_line(path, counts, sep, layout)
    text = df.to_numpy(dtype=object)
    blank = pd.isna(df).all(axis=1).to_numpy()
    values = df.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
    bad = ~blank & ~np.isfinite(values).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        j = int(np.flatnonzero(~np.isfinite(values[i]))[0])
        got = "nothing" if pd.isna(text[i, j]) else repr(str(text[i, j]))
        raise UserError(f"{path}:{i + 1}: expected {df.shape[1]} numbers ({layout}); field {j + 1} is {got}")
    keep = np.flatnonzero(~blank)
    if keep.size == 0:
        raise UserError(f"{path}: no rows; expected {layout}")
    return values[keep], keep + 1


def integral(values: np.ndarray, where: Callable[[int], str], what: str) -> np.ndarray:
    values = np.asarray(values, np.float64)
    bad = np.flatnonzero(values != np.round(values))
    if bad.size:
        raise UserError(f"{where(int(bad[0]))}: {what} must be a whole number, got {values[bad[0]]}")
    bad = np.flatnonzero(np.abs(values) >= MAX_FRAME_NUMBER)
    if bad.size:
        raise UserError(f"{where(int(bad[0]))}: {what} {values[bad[0]]:g} is out of range (|{what}| < 2^31)")
    return values.astype(np.int64)


def _check_bounded(where: Callable[[int], str], what: str, values: Any) -> None:
    """UserError at the first row of `values` (R, ...) that is not finite or exceeds MAX_COORD in size."""
    arr = np.asarray(values, np.float64).reshape(len(values), -1) if len(values) else np.zeros((0, 1))
    bad = np.flatnonzero(~(np.abs(arr) <= MAX_COORD).all(axis=1))
    if bad.size:
        raise UserError(f"{where(int(bad[0]))}: {what} {arr[bad[0]].tolist()} must be finite and within "
                        f"+-{MAX_COORD:g}")


def where_lines(path: Path, lines: np.ndarray, unit: str = "") -> Callable[[int], str]:
    return lambda i: f"{path}" if i < 0 else f"{path}:{unit}{lines[i]}"
