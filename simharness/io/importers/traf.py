"""TRAF videos (the TraPHic authors' annotations, pixels at 20 fps) -> Scenes, with each video's pixel scale
estimated from its cars' boxes."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from simharness.errors import UserError
from simharness.io.importers.source import (
    MAX_FRAME_NUMBER,
    PathLike,
    check_file,
    line_text,
    scene_from_rows,
    source_meta,
    where_lines,
)
from simharness.scene import AgentType, Scene

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
            raise UserError(f"{path}:{i}: expected {layout}; got {line_text(path, i)!r}") from None
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
        path = check_file(p)
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
        meta = source_meta(path, "traf", path.stem, units="px", image_size=list(size),
                            image_size_source="given" if image_size else "from the boxes' extent",
                            axes="image pixels: x right, y down", dropped_unlabelled=dropped,
                            unknown_classes=unknown, untyped_ids=int(bare.sum()),
                            frame_rate_source="given" if fps else "TRAF's 20 fps (data set notes)")
        scene = scene_from_rows(
            frame, ids, centre, dt=1.0 / (fps or TRAF_FPS), agent_type=codes[inverse], size=box[:, 2:4],
            extra={"box_w": box[:, 2], "box_h": box[:, 3]}, where=where_lines(path, lines), meta=meta,
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
