"""Public trajectory data sets in, as `Scene`s: ETH/UCY, TRAF, ApolloScape, CommonRoad, Argoverse 2, TrackNPred.

One function per format, each `(paths) -> list[Scene]`; `import_command` behind `simharness import`
writes them as the project's own data set (`simharness.io.parquet.write_dataset`, atomic).

Every scene's `meta` records where it came from and what its numbers mean:
`format`, `source` (file name), `source_sha256`, `units` ("m" or "px"), `frame_rate_hz`,
`source_frame_step` (source frame numbers per column), plus format notes. A frame missing from a
recording stays an invalid column: positions are never invented. Heading and speed come from the
source when it has them, else from finite differences of the positions (`motion_from_positions`).

Bad input raises `UserError` with one line naming the file, the line (or row / element) and what
was expected. Parsing is vectorised with pandas/numpy; only the error path scans lines one by one.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import re
import sys
import xml.etree.ElementTree as ET
import xml.parsers.expat as pyexpat
from collections.abc import Callable, Iterator, Sequence
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


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _source_meta(path: Path, fmt: str, scene_id: str, **more: Any) -> dict[str, Any]:
    return {"scene_id": scene_id, "scenario": scene_id, "format": fmt, "source": path.name,
            "source_sha256": _sha256(path), **more}


def _check_file(path: PathLike) -> Path:
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found" if not path.exists() else f"{path}: expected a file, got a folder")
    return path


def _line_text(path: Path, lineno: int) -> str:
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
                                 f"got {len(fields)}: {_line_text(path, i)!r}")
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


def _integral(values: np.ndarray, where: Callable[[int], str], what: str) -> np.ndarray:
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


def _where(path: Path, lines: np.ndarray, unit: str = "") -> Callable[[int], str]:
    return lambda i: f"{path}" if i < 0 else f"{path}:{unit}{lines[i]}"


# ====================================================================== ETH / UCY
ETH_UCY_DT = 0.4


def import_eth_ucy(paths: Sequence[PathLike]) -> list[Scene]:
    """ETH/UCY pedestrian files (`frame ped_id x y`, tab or space separated, metres), one scene per file.

    One column per annotated step of 0.4 s; the source frame step is inferred (10 in most files,
    6 in biwi_eth) as the commonest difference between successive frame numbers. Frames missing from a
    file stay invalid columns (the Social-GAN windowing skips them: see `simharness.protocols`).
    """
    scenes = []
    for p in paths:
        path = _check_file(p)
        vals, lines = read_numeric_table(path, (4,), "frame ped_id x y")
        where = _where(path, lines)
        frame = _integral(vals[:, 0], where, "frame")
        ped = _integral(vals[:, 1], where, "ped_id")
        diffs = np.diff(np.unique(frame))
        # The annotation step is the commonest frame difference; a frame off its grid is an error.
        values, counts = np.unique(diffs, return_counts=True)  # not bincount: a gap of 1e9 frames is one entry
        step = int(values[np.argmax(counts)]) if diffs.size else 1
        scenes.append(scene_from_rows(
            frame, ped.astype(str), vals[:, 2:4], dt=ETH_UCY_DT, frame_step=max(step, 1),
            agent_type=np.full(len(frame), AgentType.PEDESTRIAN, np.int8), where=where,
            meta=_source_meta(path, "eth-ucy", path.stem, units="m"),
        ))
    return scenes


# ====================================================================== TRAF
TRAF_FPS = 20.0  # the data set's notes; the files carry no rate (`import traf --fps` for other videos)
TRAF_DT = 1.0 / TRAF_FPS
# Video frame sizes to snap a file's box extent to (boxes run a few pixels off the frame edge).
TRAF_FRAME_SIZES = ((640, 360), (640, 480), (960, 540), (1280, 720), (1920, 1080), (2560, 1440), (3840, 2160))
TRAF_EDGE_TOLERANCE = 0.02
# Class from the id's letters; the annotators' spellings as found in the files, typos included.
TRAF_CLASSES: dict[str, AgentType] = {
    "car": AgentType.CAR, "taxi": AgentType.CAR, "jeep": AgentType.CAR, "van": AgentType.CAR,
    "bus": AgentType.BUS,
    "truck": AgentType.TRUCK, "lorry": AgentType.TRUCK, "tempo": AgentType.TRUCK,
    "rick": AgentType.RICKSHAW, "rickshaw": AgentType.RICKSHAW, "ricksaw": AgentType.RICKSHAW,
    "rikshaw": AgentType.RICKSHAW, "auto": AgentType.RICKSHAW,
    "bike": AgentType.MOTORCYCLE, "motorbike": AgentType.MOTORCYCLE, "motorcycle": AgentType.MOTORCYCLE,
    "scooter": AgentType.SCOOTER, "sccoter": AgentType.SCOOTER, "scoter": AgentType.SCOOTER,
    "scooty": AgentType.SCOOTER,
    "cycle": AgentType.BICYCLE, "bicycle": AgentType.BICYCLE, "cylce": AgentType.BICYCLE,
    "ped": AgentType.PEDESTRIAN, "man": AgentType.PEDESTRIAN, "woman": AgentType.PEDESTRIAN,
    "person": AgentType.PEDESTRIAN, "pedestrian": AgentType.PEDESTRIAN, "human": AgentType.PEDESTRIAN,
    "others": AgentType.OTHER, "other": AgentType.OTHER, "animal": AgentType.OTHER,
}
TRAF_UNLABELLED = {"null", "none", ""}
# A rough length scale for pixel data (TraPHic's ellipses and grids are in metres): a car's image box is
# about as wide as the car, seen from behind in these front-view videos; 1.7 m is a typical small car.
TRAF_CAR_WIDTH_M = 1.7
TRAF_SCALE_NOTE = ("units_per_m: median over cars of their median image-box width (px) / 1.7 m, a typical "
                   "car width seen from behind; one depth-averaged scale per video, not a homography (none is "
                   "published): it sizes interaction regions only, metrics stay in pixels")


def traf_pixels_per_metre(scene: Scene) -> float | None:
    """Estimated pixels per metre of a TRAF video (see `TRAF_SCALE_NOTE`); None when it has no cars.

    scene.length holds each agent's median image-box width in pixels."""
    cars = scene.agent_type == AgentType.CAR
    return round(float(np.median(scene.length[cars])) / TRAF_CAR_WIDTH_M, 2) if cars.any() else None


def traf_image_size(box: np.ndarray) -> tuple[int, int]:
    """(width, height) px of the video from its boxes (R, 4: x, y, w, h): the smallest common frame size
    holding every box but for a 2% edge overrun, else the boxes' extent itself."""
    w, h = float((box[:, 0] + box[:, 2]).max()), float((box[:, 1] + box[:, 3]).max())
    for fw, fh in TRAF_FRAME_SIZES:
        if w <= fw * (1 + TRAF_EDGE_TOLERANCE) and h <= fh * (1 + TRAF_EDGE_TOLERANCE):
            return fw, fh
    return int(math.ceil(w)), int(math.ceil(h))


def traf_class(agent_id: str) -> AgentType | None:
    """`AgentType` of a TRAF id from its letters ("rickshaw3" -> RICKSHAW, "sccoter1" -> SCOOTER); None if unknown."""
    letters = re.sub(r"[^a-z]", "", agent_id.lower())
    return TRAF_CLASSES.get(letters)


def _traf_rows(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(frame (R,), line (R,), boxes (R, 4) float, ids (R,) str) from `frame, n, n x (x, y, w, h, id)` lines."""
    layout = "frame, n, then n groups of x, y, w, h, id"
    frames, line_of, boxes, ids = [], [], [], []
    with open(path, encoding="utf-8", errors="replace", newline="") as f:
        lines = f.read().splitlines()
    for i, text in enumerate(lines, 1):  # one line per video frame, each split at C speed
        fields = [s.strip() for s in text.split(",")]
        if fields and fields[-1] == "":
            fields.pop()  # a trailing comma
        if not fields:
            continue
        try:
            frame, n = int(fields[0]), int(fields[1])
        except (ValueError, IndexError):
            raise UserError(f"{path}:{i}: expected {layout}; got {_line_text(path, i)!r}") from None
        if not -MAX_FRAME_NUMBER < frame < MAX_FRAME_NUMBER:
            raise UserError(f"{path}:{i}: frame {frame} is out of range (|frame| < 2^31)")
        if n < 0 or len(fields) != 2 + 5 * n:
            raise UserError(f"{path}:{i}: says {n} agents, so {2 + 5 * n} fields ({layout}); got {len(fields)}")
        groups = np.array(fields[2:], dtype=object).reshape(n, 5)
        try:
            box = groups[:, :4].astype(np.float64)
        except ValueError:
            bad = next(g for g in groups[:, :4].ravel() if not re.fullmatch(r"[-+.\deE]+", g))
            raise UserError(f"{path}:{i}: expected numbers for x, y, w, h; got {bad!r}") from None
        if not np.isfinite(box).all():
            raise UserError(f"{path}:{i}: x, y, w, h must be finite numbers")
        frames.append(np.full(n, frame, np.int64))
        line_of.append(np.full(n, i, np.int64))
        boxes.append(box)
        ids.append(groups[:, 4].astype(str))
    if not frames:
        raise UserError(f"{path}: empty file; expected lines of {layout}")
    return np.concatenate(frames), np.concatenate(line_of), np.concatenate(boxes), np.concatenate(ids)


def import_traf(paths: Sequence[PathLike], type_default: str | None = None, pixel_scale: float | None = None,
                fps: float | None = None, image_size: tuple[int, int] | None = None) -> list[Scene]:
    """TRAF ground-truth files (one line per frame: frame, n, then n x (x, y, w, h, id)), one scene per video.

    Units are image pixels of the front-view video (x right, y down; no homography is published).
    x, y is a box's top-left corner: the agent is its centre. The class is the id's letters
    (`TRAF_CLASSES`, typos included); unlabelled boxes ("null") are dropped and counted in
    `meta["dropped_unlabelled"]`, as are second boxes of one id in one frame (`meta["dropped_duplicates"]`,
    27 in TRAF12); unknown classes become OTHER, counted in `meta["unknown_classes"]`. Ids that are bare
    numbers (no class in the file) get `type_default` (a label, e.g. "car"; else OTHER), and the scene's
    `meta["warnings"]` says so. length, width: the median box width and height (pixels, the image box, not
    a ground footprint); the box per frame is kept in `extra["box_w"]`, `extra["box_h"]`.
    `meta["units_per_m"]`: pixels per metre, estimated from the cars' boxes (`traf_pixels_per_metre`; cars
    typed by `type_default` count) so that predictors with regions in metres can size them; a video without
    cars takes `pixel_scale` (metres per pixel) when given, else has none and a warning. Errors stay in
    pixels (evaluation uses the scale only for thresholds: the 2 m miss distance and the density radius).
    fps: frames per second (the files carry none; 20 per the data set's notes). image_size: (width, height)
    px, else from the boxes (`traf_image_size`).
    """
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise UserError(f"--fps {fps}: expected a positive frame rate")
    if pixel_scale is not None and not (math.isfinite(pixel_scale) and pixel_scale > 0):
        raise UserError(f"--pixel-scale {pixel_scale}: expected positive metres per pixel, e.g. 0.02")
    default = AgentType.OTHER if type_default is None else AgentType.parse(type_default)
    scenes = []
    for p in paths:
        path = _check_file(p)
        frame, lines, box, ids = _traf_rows(path)
        keep = ~np.isin(np.char.lower(ids), list(TRAF_UNLABELLED))
        dropped = int((~keep).sum())
        frame, lines, box, ids = frame[keep], lines[keep], box[keep], ids[keep]
        uniq, inverse = np.unique(ids, return_inverse=True)
        bare = np.array([re.fullmatch(r"[-+]?\d+", u) is not None for u in uniq], bool)
        classes = [default if b else traf_class(u) for u, b in zip(uniq, bare, strict=True)]
        unknown = {u: int((inverse == k).sum()) for k, u in enumerate(uniq) if classes[k] is None}
        codes = np.array([AgentType.OTHER if c is None else c for c in classes], np.int8)
        centre = box[:, :2] + box[:, 2:4] / 2
        size = image_size or traf_image_size(box)
        warnings = []
        if bare.any():
            how = f"typed {default.label} (--type-default)" if type_default else \
                "typed other; give --type-default TYPE"
            warnings.append(f"{path.name}: {int(bare.sum())} of {len(uniq)} ids carry no class (bare numbers): {how}")
        meta = _source_meta(path, "traf", path.stem, units="px", image_size=list(size),
                            image_size_source="given" if image_size else "from the boxes' extent",
                            axes="image pixels: x right, y down", dropped_unlabelled=dropped,
                            unknown_classes=unknown, untyped_ids=int(bare.sum()),
                            frame_rate_source="given" if fps else "TRAF's 20 fps (data set notes)")
        scene = scene_from_rows(
            frame, ids, centre, dt=1.0 / (fps or TRAF_FPS), agent_type=codes[inverse], size=box[:, 2:4],
            extra={"box_w": box[:, 2], "box_h": box[:, 3]}, where=_where(path, lines), meta=meta,
            duplicates="first",
        )
        scale = traf_pixels_per_metre(scene)
        if scale is not None:
            scale_meta = {"units_per_m": scale, "units_per_m_note": TRAF_SCALE_NOTE}
        elif pixel_scale is not None:
            scale_meta = {"units_per_m": round(1.0 / pixel_scale, 4),
                          "units_per_m_note": f"given: --pixel-scale {pixel_scale:g} m/px (no cars to estimate it)"}
        else:
            scale_meta = {}
            warnings.append(f"{path.name}: no cars to estimate a pixel scale from; give --pixel-scale M_PER_PX "
                            "(or --type-default car) to train or evaluate on it")
        warnings[1:] = [w.removeprefix(f"{path.name}: ") for w in warnings[1:]]
        scenes.append(scene.replace(meta={**scene.meta, **scale_meta, "warnings": warnings}))
    return scenes


# ====================================================================== ApolloScape
APOLLO_DT = 0.5
APOLLO_TYPES = {1: AgentType.CAR, 2: AgentType.BUS, 3: AgentType.PEDESTRIAN, 4: AgentType.BICYCLE,
                5: AgentType.OTHER}
APOLLO_TYPE_NOTE = "1 small vehicle->car, 2 big vehicle->bus, 3 pedestrian, 4 bicyclist/motorcyclist->bicycle, 5 other"


def import_apolloscape(paths: Sequence[PathLike], max_gap: int = 1) -> list[Scene]:
    """ApolloScape trajectory files (`frame id type x y [z length width height heading]`, metres, 2 Hz).

    Files come as separate chunks of a few frames: a jump of more than `max_gap` frames starts a
    new scene (id `<file>-<first frame>`). With the 10-column layout the source's sizes and
    heading are used; with 5 columns, the type's default footprint and finite-difference heading.
    """
    layout = "frame id type x y [z length width height heading]"
    scenes = []
    for p in paths:
        path = _check_file(p)
        vals, lines = read_numeric_table(path, (5, 10), layout)
        where = _where(path, lines)
        frame = _integral(vals[:, 0], where, "frame")
        obj = _integral(vals[:, 1], where, "object id")
        code = _integral(vals[:, 2], where, "object type")
        bad = np.flatnonzero(~np.isin(code, list(APOLLO_TYPES)))
        if bad.size:
            raise UserError(f"{path}:{lines[bad[0]]}: object type {code[bad[0]]}; expected one of 1-5 "
                            f"({APOLLO_TYPE_NOTE})")
        lut = np.zeros(max(APOLLO_TYPES) + 1, np.int8)
        lut[list(APOLLO_TYPES)] = list(APOLLO_TYPES.values())
        uf = np.unique(frame)
        starts = uf[np.r_[0, np.flatnonzero(np.diff(uf) > max_gap) + 1]]
        chunk = np.searchsorted(starts, frame, side="right") - 1
        full = vals.shape[1] == 10
        for k, start in enumerate(starts):
            rows = np.flatnonzero(chunk == k)
            scene_id = f"{path.stem}-{int(start):06d}"
            meta = _source_meta(path, "apolloscape", scene_id, units="m", type_map=APOLLO_TYPE_NOTE,
                                source_lines=[int(lines[rows].min()), int(lines[rows].max())])
            scenes.append(scene_from_rows(
                frame[rows], obj[rows].astype(str), vals[rows, 3:5], dt=APOLLO_DT, agent_type=lut[code[rows]],
                size=vals[rows][:, [6, 7]] if full else None, heading=vals[rows, 9] if full else None,
                where=_where(path, lines[rows]), meta=meta,  # speed from positions
            ))
    return scenes


# ====================================================================== CommonRoad XML
COMMONROAD_TYPES = {
    "car": AgentType.CAR, "taxi": AgentType.CAR, "priorityVehicle": AgentType.CAR, "parkedVehicle": AgentType.CAR,
    "truck": AgentType.TRUCK, "bus": AgentType.BUS, "motorcycle": AgentType.MOTORCYCLE,
    "bicycle": AgentType.BICYCLE, "pedestrian": AgentType.PEDESTRIAN,
}


def _parse_xml(path: Path) -> tuple[ET.Element, dict[int, int]]:
    """Element tree plus each element's source line (keyed by id(element)), for error messages."""
    expat = pyexpat.ParserCreate()
    builder = ET.TreeBuilder()
    lines: dict[int, int] = {}

    def start(tag: str, attrs: dict[str, str]) -> None:
        lines[id(builder.start(tag, attrs))] = expat.CurrentLineNumber

    expat.StartElementHandler = start
    expat.EndElementHandler = builder.end
    expat.CharacterDataHandler = builder.data
    try:
        expat.Parse(path.read_bytes(), True)
    except pyexpat.ExpatError as e:
        raise UserError(f"{path}:{e.lineno}: not well-formed XML ({pyexpat.ErrorString(e.code)})") from None
    return builder.close(), lines


def _cr_value(elem: ET.Element, tag: str, path: Path, lines: dict[int, int]) -> float:
    """`<tag><exact>v</exact></tag>` or an interval's midpoint; UserError naming the line if missing."""
    node = elem.find(tag)
    if node is None:
        raise UserError(f"{path}:{lines.get(id(elem), 0)}: <{elem.tag}> lacks <{tag}>")
    exact = node.findtext("exact")
    try:
        if exact is not None:
            return float(exact)
        return (float(node.findtext("intervalStart")) + float(node.findtext("intervalEnd"))) / 2
    except (TypeError, ValueError):
        raise UserError(f"{path}:{lines.get(id(node), 0)}: <{tag}> needs a number in <exact> "
                        f"or <intervalStart>/<intervalEnd>") from None


def _cr_point(state: ET.Element, path: Path, lines: dict[int, int]) -> tuple[float, float]:
    pt = state.find("position/point")
    if pt is None:
        raise UserError(f"{path}:{lines.get(id(state), 0)}: <{state.tag}> lacks <position><point>")
    try:
        return float(pt.findtext("x")), float(pt.findtext("y"))
    except (TypeError, ValueError):
        raise UserError(f"{path}:{lines.get(id(pt), 0)}: <point> needs numeric <x> and <y>") from None


def _cr_road(root: ET.Element) -> dict[str, Any]:
    """Lanelets as a `RoadGeometry` dict: each lanelet a drivable polygon, its bounds as markings."""
    drivable, markings = [], []
    for lanelet in root.iter("lanelet"):
        bounds = []
        for side in ("leftBound", "rightBound"):
            pts = [(float(p.findtext("x")), float(p.findtext("y"))) for p in lanelet.findall(f"{side}/point")]
            bounds.append(np.round(np.asarray(pts, np.float64).reshape(-1, 2), 3))
        if len(bounds[0]) >= 2 and len(bounds[1]) >= 2:
            drivable.append(np.concatenate([bounds[0], bounds[1][::-1]]).tolist())
            markings.extend(b.tolist() for b in bounds)
    return {"drivable": drivable, "sidewalks": [], "markings": markings}


def import_commonroad(paths: Sequence[PathLike]) -> list[Scene]:
    """CommonRoad XML scenarios (e.g. the NGSIM US-101 ones), one scene per file, metres.

    Each `dynamicObstacle` is an agent: its `shape/rectangle` gives length and width (a circle gives
    its diameter), `initialState` and `trajectory/state` give position, orientation, velocity at
    integer time steps of `timeStepSize` seconds. The lanelets become the scene's road geometry
    (`meta["road"]`); the planning problem's initial state is kept in `meta["planning_problem"]`.
    """
    scenes = []
    for p in paths:
        path = _check_file(p)
        root, lines = _parse_xml(path)
        if root.tag != "commonRoad":
            raise UserError(f"{path}:1: root element is <{root.tag}>; expected <commonRoad>")
        try:
            dt = float(root.get("timeStepSize", ""))
        except ValueError:
            raise UserError(f"{path}:1: <commonRoad> needs a numeric timeStepSize attribute") from None
        frame, agent, xy, head, speed, size, kinds, where = [], [], [], [], [], [], [], []
        unknown: dict[str, int] = {}
        for obs in root.iter("dynamicObstacle"):
            oid = obs.get("id")
            line = lines.get(id(obs), 0)
            if oid is None:
                raise UserError(f"{path}:{line}: <dynamicObstacle> lacks its id attribute")
            kind = (obs.findtext("type") or "").strip()
            if kind not in COMMONROAD_TYPES:
                unknown[kind] = unknown.get(kind, 0) + 1
            rect = obs.find("shape/rectangle")
            circle = obs.find("shape/circle")
            try:
                if rect is not None:
                    dims = (float(rect.findtext("length")), float(rect.findtext("width")))
                elif circle is not None:
                    dims = (2 * float(circle.findtext("radius")),) * 2
                else:
                    dims = AgentType.OTHER.footprint if kind not in COMMONROAD_TYPES else \
                        COMMONROAD_TYPES[kind].footprint
            except (TypeError, ValueError):
                raise UserError(f"{path}:{line}: obstacle {oid}: <shape> needs numeric length/width or radius") \
                    from None
            init = obs.find("initialState")
            if init is None:
                raise UserError(f"{path}:{line}: obstacle {oid} lacks <initialState>")
            for state in [init, *obs.findall("trajectory/state")]:
                frame.append(_cr_value(state, "time", path, lines))
                xy.append(_cr_point(state, path, lines))
                head.append(_cr_value(state, "orientation", path, lines))
                speed.append(_cr_value(state, "velocity", path, lines))
                agent.append(oid)
                size.append(dims)
                kinds.append(COMMONROAD_TYPES.get(kind, AgentType.OTHER))
                where.append(lines.get(id(state), 0))
        where_arr = np.asarray(where)
        frame_arr = _integral(np.asarray(frame), _where(path, where_arr), "<time>")
        planning = root.find("planningProblem/initialState")
        meta = _source_meta(path, "commonroad", path.stem, units="m", benchmark_id=root.get("benchmarkID", ""),
                            commonroad_version=root.get("commonRoadVersion", ""), road=_cr_road(root),
                            unknown_classes=unknown, static_obstacles=len(root.findall("staticObstacle")))
        if planning is not None:
            meta["planning_problem"] = {"xy": list(_cr_point(planning, path, lines)),
                                        "velocity": _cr_value(planning, "velocity", path, lines),
                                        "orientation": _cr_value(planning, "orientation", path, lines)}
        scenes.append(scene_from_rows(
            frame_arr, np.asarray(agent), np.asarray(xy, np.float64).reshape(-1, 2), dt=dt,
            agent_type=np.asarray(kinds, np.int8), heading=np.asarray(head), speed=np.asarray(speed),
            size=np.asarray(size, np.float64).reshape(-1, 2), where=_where(path, where_arr), meta=meta,
        ))
    return scenes


# ====================================================================== Argoverse 2
AV2_DT = 0.1
AV2_TYPES = {
    "vehicle": AgentType.CAR, "bus": AgentType.BUS, "motorcyclist": AgentType.MOTORCYCLE,
    "cyclist": AgentType.BICYCLE, "riderless_bicycle": AgentType.BICYCLE, "pedestrian": AgentType.PEDESTRIAN,
    "static": AgentType.OTHER, "background": AgentType.OTHER, "construction": AgentType.OTHER,
    "unknown": AgentType.OTHER,
}
AV2_COLUMNS = ("track_id", "object_type", "object_category", "timestep", "position_x", "position_y", "heading",
               "velocity_x", "velocity_y", "observed")
AV2_EGO = "AV"


def import_argoverse2(paths: Sequence[PathLike]) -> list[Scene]:
    """Argoverse 2 motion-forecasting scenario Parquet files, one scene per file, metres, 10 Hz.

    The autonomous vehicle (track "AV") is the scene's ego; the focal track and the scored tracks
    (object_category 3 and 2) are listed in `meta["focal_agent"]` and `meta["scored_agents"]`;
    `extra["observed"]` is 1 where the source marks a step as observed (history), else 0.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    scenes = []
    for p in paths:
        path = _check_file(p)
        try:
            table = pq.read_table(path)
        except (OSError, pa.ArrowException) as e:
            raise UserError(f"{path}: not a readable Parquet file ({str(e).splitlines()[0][:120]})") from None
        missing = [c for c in AV2_COLUMNS if c not in table.column_names]
        if missing:
            raise UserError(f"{path}: missing column {missing[0]!r}; an Argoverse 2 scenario has "
                            f"{', '.join(AV2_COLUMNS)}")
        df = table.select([c for c in (*AV2_COLUMNS, "focal_track_id", "scenario_id", "city")
                           if c in table.column_names]).to_pandas()
        num = df[["timestep", "position_x", "position_y", "heading", "velocity_x", "velocity_y"]].to_numpy(
            np.float64)
        rows = np.arange(len(df))
        bad = np.flatnonzero(~np.isfinite(num).all(axis=1))
        if bad.size:
            raise UserError(f"{path}:row {bad[0]}: timestep, position, heading and velocity must be finite")
        frame = _integral(num[:, 0], _where(path, rows, "row "), "timestep")
        kind = df["object_type"].astype(str).to_numpy()
        unknown = sorted(set(kind) - set(AV2_TYPES))
        codes = np.array([AV2_TYPES.get(k, AgentType.OTHER) for k in kind], np.int8) if len(kind) else \
            np.zeros(0, np.int8)
        track = df["track_id"].astype(str).to_numpy()
        cat = df.groupby("track_id", sort=True)["object_category"].max()
        focal = str(df["focal_track_id"].iloc[0]) if "focal_track_id" in df and len(df) else \
            (cat.index[cat == 3].tolist() or [""])[0]
        scenario = str(df["scenario_id"].iloc[0]) if "scenario_id" in df and len(df) else path.stem
        meta = _source_meta(path, "argoverse2", scenario, units="m", focal_agent=focal,
                            scored_agents=sorted(cat.index[cat >= 2].astype(str)), ego_agent=AV2_EGO,
                            city=str(df["city"].iloc[0]) if "city" in df and len(df) else "",
                            unknown_classes=unknown)
        scenes.append(scene_from_rows(
            frame, track, num[:, 1:3], dt=AV2_DT, agent_type=codes, heading=num[:, 3],
            speed=np.hypot(num[:, 4], num[:, 5]), extra={"observed": df["observed"].to_numpy(np.float32)},
            where=_where(path, rows, "row "), meta=meta, ego_id=AV2_EGO,
        ))
    return scenes


# ====================================================================== TrackNPred (TraPHic authors' layout)
TRACKNPRED_DT = TRAF_DT
PICKLE_REFUSAL = ("{path}: a pickled NumPy object array: loading it can run arbitrary code, so it is refused; "
                  "import the .txt beside it, or pass --allow-pickle if you trust this file")


def _tracknpred_rows(path: Path, allow_pickle: bool) -> tuple[np.ndarray, np.ndarray]:
    """(values (R, 5): dataset, id, frame, x, y; line or row numbers (R,)) from any TrackNPred file."""
    if path.suffix == ".npy":
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
        path = _check_file(p)
        vals, lines = _tracknpred_rows(path, allow_pickle)
        where = _where(path, lines, "row " if path.suffix == ".npy" else "")
        ds = _integral(vals[:, 0], where, "dataset id")
        ids = _integral(vals[:, 1], where, "agent id")
        frame = _integral(vals[:, 2], where, "frame")
        exported = _export_info(path)
        for d in np.unique(ds):
            rows = np.flatnonzero(ds == d)
            scene_id = f"{path.stem}-ds{int(d)}"
            known = exported.get(str(int(d)), {})
            note = "from simharness_export.json" if known else "not in the layout; TRAF's 20 fps assumed"
            meta = _source_meta(path, "tracknpred", scene_id, units=known.get("units", "px"), dataset_id=int(d),
                                frame_rate_note=note, exported_scene=known.get("scene_id", ""))
            scenes.append(scene_from_rows(
                frame[rows], ids[rows].astype(str), vals[rows, 3:5], dt=float(known.get("dt", dt)),
                agent_type=np.full(rows.size, AgentType.OTHER, np.int8),
                where=_where(path, lines[rows], "row " if path.suffix == ".npy" else ""),
                meta=meta,
            ))
    return scenes


# ====================================================================== the command
IMPORTERS: dict[str, tuple[Callable[..., list[Scene]], tuple[str, ...]]] = {
    "eth-ucy": (import_eth_ucy, ("*.txt",)),
    "traf": (import_traf, ("*.txt",)),
    "apolloscape": (import_apolloscape, ("*.txt",)),
    "commonroad": (import_commonroad, ("*.xml",)),
    "argoverse2": (import_argoverse2, ("*.parquet",)),
    "tracknpred": (import_tracknpred, ("*.txt",)),
}
ALIASES = {"eth": "eth-ucy", "ucy": "eth-ucy", "ethucy": "eth-ucy", "eth_ucy": "eth-ucy", "av2": "argoverse2",
           "apollo": "apolloscape", "ngsim": "commonroad", "commonroad-xml": "commonroad"}


def format_name(name: str) -> str:
    """Canonical format name; UserError listing the choices otherwise."""
    key = ALIASES.get(name.strip().lower(), name.strip().lower())
    if key not in IMPORTERS:
        raise UserError(f"unknown import format {name!r}; expected one of {', '.join(IMPORTERS)}")
    return key


def source_files(fmt: str, sources: Sequence[PathLike]) -> list[Path]:
    """Files named, and the format's files inside folders named (sorted); UserError if none."""
    files: list[Path] = []
    for src in map(Path, sources):
        if src.is_dir():
            found = sorted(f for pat in IMPORTERS[fmt][1] for f in src.glob(pat) if f.is_file())
            if not found:
                raise UserError(f"{src}: no {' or '.join(IMPORTERS[fmt][1])} files for format {fmt}")
            files.extend(found)
        elif src.is_file():
            files.append(src)
        else:
            raise UserError(f"{src}: not found")
    return files


def import_scenes(fmt: str, files: Sequence[PathLike], allow_pickle: bool = False,
                  options: dict[str, Any] | None = None) -> Iterator[Scene]:
    """Scenes of `files` in `fmt`, file by file; scene ids made unique across files.
    options: the format's own keyword arguments (`import_traf`: type_default, pixel_scale, fps, image_size)."""
    fn = IMPORTERS[format_name(fmt)][0]
    seen: dict[str, Path] = {}
    for f in files:
        kwargs = {"allow_pickle": allow_pickle} if fn is import_tracknpred else {}
        try:
            scenes = fn([f], **kwargs, **(options or {}))
        except UserError:
            raise
        except Exception as e:  # safety net: a source we did not foresee is still one line naming the file
            msg = str(e).strip().splitlines()[0][:160] if str(e).strip() else ""
            raise UserError(f"{f}: cannot be read as {format_name(fmt)} ({type(e).__name__}: {msg})") from None
        for scene in scenes:
            sid = scene.meta["scene_id"]
            if sid in seen:
                raise UserError(f"{f}: scene id {sid!r} already taken by {seen[sid]}; rename one of the files")
            seen[sid] = Path(f)
            yield scene


def traf_options(args: argparse.Namespace) -> dict[str, Any]:
    """The `import traf` options the user gave (--type-default, --pixel-scale, --fps, --image-size WxH)."""
    options = {k: getattr(args, k, None) for k in ("type_default", "pixel_scale", "fps", "image_size")}
    options = {k: v for k, v in options.items() if v is not None}
    if "image_size" in options:
        m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(options["image_size"]))
        if not m or min(int(m[1]), int(m[2])) < 1:
            raise UserError(f"--image-size {options['image_size']!r}: expected WIDTHxHEIGHT in pixels, e.g. 1280x720")
        options["image_size"] = (int(m[1]), int(m[2]))
    if "type_default" in options:
        AgentType.parse(options["type_default"])  # one line naming the choices, before any file is read
    return options


def import_command(args: argparse.Namespace) -> int:
    """`simharness import FORMAT SRC... --out DIR [--allow-pickle]`: write a data set, print a summary."""
    from tqdm import tqdm

    from simharness.io.parquet import write_dataset

    fmt = format_name(args.format)
    options = traf_options(args)
    if options and fmt != "traf":
        raise UserError(f"--{next(iter(options)).replace('_', '-')} is an option of `import traf`, not of {fmt}")
    files = source_files(fmt, args.src)
    summary: dict[str, Any] = {"scenes": 0, "agents": 0, "agent_frames": 0, "frames": 0, "units": set(),
                               "rate": set(), "types": {}}

    def scenes() -> Iterator[Scene]:
        for scene in import_scenes(fmt, tqdm(files, desc=f"import {fmt}", unit="file", file=sys.stderr),
                                   allow_pickle=args.allow_pickle, options=options):
            if scene.meta.get("warnings"):  # one line per file
                tqdm.write(f"simharness: warning: {'; '.join(scene.meta['warnings'])}", file=sys.stderr)
            summary["scenes"] += 1
            summary["agents"] += scene.num_agents
            summary["agent_frames"] += int(scene.valid.sum())
            summary["frames"] += scene.num_frames
            summary["units"].add(scene.units)
            summary["rate"].add(scene.meta["frame_rate_hz"])
            for code, count in zip(*np.unique(scene.agent_type, return_counts=True), strict=True):
                label = AgentType(int(code)).label
                summary["types"][label] = summary["types"].get(label, 0) + int(count)
            yield scene
        if not summary["scenes"]:  # raised inside the writer's block: the half-made folder is removed
            raise UserError(f"{', '.join(map(str, files))[:200]}: no trajectory rows found; nothing to import")

    info = {"source": {"format": fmt, "files": [{"name": f.name, "sha256": _sha256(f)} for f in files]},
            "importer": "simharness.io.importers", "allow_pickle": bool(args.allow_pickle)}
    out = write_dataset(scenes(), args.out, info)
    units = "/".join(sorted(summary["units"]))
    rate = "/".join(f"{r:g}" for r in sorted(summary["rate"]))
    types = ", ".join(f"{k} {v}" for k, v in sorted(summary["types"].items(), key=lambda kv: -kv[1]))
    print(f"imported {fmt}: {len(files)} file(s) -> {summary['scenes']} scene(s), {summary['agents']} agents "
          f"({types}), {summary['agent_frames']} agent-frames over {summary['frames']} frames at {rate} Hz, "
          f"units {units}; wrote {out}")
    return 0
