"""Public trajectory data sets in, as `Scene`s: ETH/UCY, TRAF, ApolloScape, CommonRoad, Argoverse 2, TrackNPred.

One module per format (`eth_ucy`, `traf`, `apolloscape`, `commonroad`, `argoverse2`, `tracknpred`), each with an
`import_*(paths) -> list[Scene]` built on `source`; this package's `import_command`, behind
`simharness import`, writes them as the project's own data set (`simharness.io.parquet.write_dataset`, atomic).

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
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.io.importers.apolloscape import import_apolloscape
from simharness.io.importers.argoverse2 import import_argoverse2
from simharness.io.importers.commonroad import import_commonroad
from simharness.io.importers.eth_ucy import import_eth_ucy
from simharness.io.importers.source import PathLike, motion_from_positions, sha256_file
from simharness.io.importers.tracknpred import import_tracknpred
from simharness.io.importers.traf import import_traf, traf_class
from simharness.scene import AgentType, Scene

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

    from simharness.io.folders import prepare_output
    from simharness.io.parquet import write_dataset

    prepare_output(args.out, force=True)  # before reading any source: never inside a data set (non-empty: below)
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

    info = {"source": {"format": fmt, "files": [{"name": f.name, "sha256": sha256_file(f)} for f in files]},
            "importer": "simharness.io.importers", "allow_pickle": bool(args.allow_pickle)}
    out = write_dataset(scenes(), args.out, info)
    units = "/".join(sorted(summary["units"]))
    rate = "/".join(f"{r:g}" for r in sorted(summary["rate"]))
    types = ", ".join(f"{k} {v}" for k, v in sorted(summary["types"].items(), key=lambda kv: -kv[1]))
    print(f"imported {fmt}: {len(files)} file(s) -> {summary['scenes']} scene(s), {summary['agents']} agents "
          f"({types}), {summary['agent_frames']} agent-frames over {summary['frames']} frames at {rate} Hz, "
          f"units {units}; wrote {out}")
    return 0


__all__ = ["import_apolloscape", "import_argoverse2", "import_command", "import_commonroad", "import_eth_ucy",
           "import_scenes", "import_tracknpred", "import_traf", "motion_from_positions", "traf_class"]
