"""ETH/UCY pedestrian files (`frame id x y`, 2.5 Hz) -> Scenes."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simharness.io.importers.source import (
    PathLike,
    check_file,
    integral,
    read_numeric_table,
    scene_from_rows,
    source_meta,
    where_lines,
)
from simharness.scene import AgentType, Scene

ETH_UCY_DT = 0.4


def import_eth_ucy(paths: Sequence[PathLike]) -> list[Scene]:
    """ETH/UCY pedestrian files (`frame ped_id x y`, tab or space separated, metres), one scene per file.

    One column per annotated step of 0.4 s; the source frame step is inferred (10 in most files,
    6 in biwi_eth) as the commonest difference between successive frame numbers. Frames missing from a
    file stay invalid columns (the Social-GAN windowing skips them: see `simharness.protocols`).
    """
    scenes = []
    for p in paths:
        path = check_file(p)
        vals, lines = read_numeric_table(path, (4,), "frame ped_id x y")
        where = where_lines(path, lines)
        frame = integral(vals[:, 0], where, "frame")
        ped = integral(vals[:, 1], where, "ped_id")
        diffs = np.diff(np.unique(frame))
        # The annotation step is the commonest frame difference; a frame off its grid is an error.
        values, counts = np.unique(diffs, return_counts=True)  # not bincount: a gap of 1e9 frames is one entry
        step = int(values[np.argmax(counts)]) if diffs.size else 1
        scenes.append(scene_from_rows(
            frame, ped.astype(str), vals[:, 2:4], dt=ETH_UCY_DT, frame_step=max(step, 1),
            agent_type=np.full(len(frame), AgentType.PEDESTRIAN, np.int8), where=where,
            meta=source_meta(path, "eth-ucy", path.stem, units="m"),
        ))
    return scenes
