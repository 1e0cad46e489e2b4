"""Argoverse 2 motion-forecasting scenario Parquet files -> Scenes."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simharness.errors import UserError
from simharness.io.importers.source import (
    PathLike,
    check_file,
    integral,
    scene_from_rows,
    source_meta,
    where_lines,
)
from simharness.scene import AgentType, Scene

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
        path = check_file(p)
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
        frame = integral(num[:, 0], where_lines(path, rows, "row "), "timestep")
        kind = df["object_type"].astype(str).to_numpy()
        unknown = sorted(set(kind) - set(AV2_TYPES))
        codes = np.array([AV2_TYPES.get(k, AgentType.OTHER) for k in kind], np.int8) if len(kind) else \
            np.zeros(0, np.int8)
        track = df["track_id"].astype(str).to_numpy()
        cat = df.groupby("track_id", sort=True)["object_category"].max()
        focal = str(df["focal_track_id"].iloc[0]) if "focal_track_id" in df and len(df) else \
            (cat.index[cat == 3].tolist() or [""])[0]
        scenario = str(df["scenario_id"].iloc[0]) if "scenario_id" in df and len(df) else path.stem
        meta = source_meta(path, "argoverse2", scenario, units="m", focal_agent=focal,
                            scored_agents=sorted(cat.index[cat >= 2].astype(str)), ego_agent=AV2_EGO,
                            city=str(df["city"].iloc[0]) if "city" in df and len(df) else "",
                            unknown_classes=unknown)
        scenes.append(scene_from_rows(
            frame, track, num[:, 1:3], dt=AV2_DT, agent_type=codes, heading=num[:, 3],
            speed=np.hypot(num[:, 4], num[:, 5]), extra={"observed": df["observed"].to_numpy(np.float32)},
            where=where_lines(path, rows, "row "), meta=meta, ego_id=AV2_EGO,
        ))
    return scenes
