"""ApolloScape trajectory files (2 Hz, typed) -> Scenes."""

from __future__ import annotations

from collections.abc import Sequence

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
from simharness.scene import AgentType, Scene

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
        path = check_file(p)
        vals, lines = read_numeric_table(path, (5, 10), layout)
        where = where_lines(path, lines)
        frame = integral(vals[:, 0], where, "frame")
        obj = integral(vals[:, 1], where, "object id")
        code = integral(vals[:, 2], where, "object type")
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
            meta = source_meta(path, "apolloscape", scene_id, units="m", type_map=APOLLO_TYPE_NOTE,
                                source_lines=[int(lines[rows].min()), int(lines[rows].max())])
            scenes.append(scene_from_rows(
                frame[rows], obj[rows].astype(str), vals[rows, 3:5], dt=APOLLO_DT, agent_type=lut[code[rows]],
                size=vals[rows][:, [6, 7]] if full else None, heading=vals[rows, 9] if full else None,
                where=where_lines(path, lines[rows]), meta=meta,  # speed from positions
            ))
    return scenes
