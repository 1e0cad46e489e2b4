"""Our data sets out, in the layouts other tools read.

`export_tracknpred` writes what the TraPHic authors' TrackNPred code (and its CS-LSTM) reads: per
scene a folder `SIM<dsId>/` holding `formatted_hypo.txt`, comma-separated `dsId,id,frame,x,y`
without a header (what their `import_data` turns into the `.npy` their data loader opens; the
dataset id is also the folder's number, as their code parses it from the name). Their loader walks
each track by row offsets and treats id 0 as "no neighbour", so ids start at 1 and every id's
frames are consecutive: a track with a gap is split into one id per unbroken run. `index.csv`
maps every (dsId, id) back to the scene and agent; `README.txt` states units and frame rate, and
`simharness_export.json` records them per dsId for `simharness import tracknpred`.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
from pathlib import Path

import numpy as np
import pandas as pd

from simharness.errors import UserError
from simharness.scene import AgentType, Scene

TRACKNPRED_FILE = "formatted_hypo.txt"
EXPORT_INFO = "simharness_export.json"  # units and dt per dsId, so `simharness import tracknpred` reads them back


def track_runs(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unbroken runs of valid frames: valid (N, T) bool -> (row, start, stop) each (R,), row-major order."""
    pad = np.pad(valid, ((0, 0), (1, 1))).astype(np.int8)
    edge = np.diff(pad, axis=1)  # +1 where a run starts, -1 one past where it ends
    row, start = np.nonzero(edge == 1)
    _, stop = np.nonzero(edge == -1)
    return row, start, stop


def tracknpred_rows(scene: Scene, ds_id: int) -> tuple[np.ndarray, list[tuple[int, str, str, int, int]]]:
    """One scene -> rows (R, 5) float64 of dsId, id, frame, x, y sorted by (id, frame), and the id index.

    index entries: (id, agent_id, agent type label, first frame, last frame).
    """
    row, start, stop = track_runs(scene.valid)
    lengths = stop - start
    new_id = np.repeat(np.arange(1, row.size + 1), lengths)
    agent = np.repeat(row, lengths)
    # Column of every row: start of its run plus the offset inside it.
    col = np.repeat(start, lengths) + (np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths))
    frame = scene.frame0 + col
    xy = scene.xy[agent, col].astype(np.float64)
    rows = np.column_stack([np.full(agent.size, ds_id), new_id, frame, xy])
    index = [(int(i + 1), str(scene.agent_id[r]), AgentType(int(scene.agent_type[r])).label,
              int(scene.frame0 + a), int(scene.frame0 + b - 1)) for i, (r, a, b) in enumerate(zip(row, start, stop,
                                                                                                  strict=True))]
    return rows, index


def _readme(n_scenes: int, units: set[str], rates: set[float]) -> str:
    unit = "/".join(sorted(units))
    rate = "/".join(f"{r:g}" for r in sorted(rates))
    hz = min(rates) if rates else 1.0
    return (
        "simharness export for the TraPHic authors' TrackNPred / CS-LSTM code\n"
        f"{n_scenes} scene(s); SIM<dsId>/{TRACKNPRED_FILE}: dsId,id,frame,x,y (comma separated, no header)\n"
        f"positions in {unit}, {rate} frames per second (frames are consecutive integers per id)\n"
        "ids start at 1 per scene; a track with a gap is split into one id per unbroken run (index.csv maps back)\n"
        "their pipeline: model.Tracking.import_data.import_data(formatted_hypo, H, npy, sgan_txt) per folder,\n"
        "then merge_n_split; their loader's t_h and t_f count frames: for 3 s of history and 5 s of future at\n"
        f"this rate use t_h={round(3 * hz)}, t_f={round(5 * hz)}.\n"
    )


def export_tracknpred(dataset_dir: Path, out: Path) -> Path:
    """Write a data set in the TrackNPred layout (see the module doc) to `out`, atomically; returns `out`.

    Scene i of the data set (in manifest order) becomes dataset id i + 1. Refuses a non-empty `out`.
    """
    from simharness.io.folders import prepare_output
    from simharness.io.parquet import Dataset, atomic_folder

    out = prepare_output(Path(out), force=True)  # never inside a data set (non-empty: atomic_folder refuses)
    data = Dataset(Path(dataset_dir))
    with atomic_folder(out) as tmp:
        index = io.StringIO()
        table = csv.writer(index, lineterminator="\n")
        table.writerow(["dsId", "id", "scene_id", "agent_id", "agent_type", "first_frame", "last_frame"])
        units, rates, scenes = set(), set(), {}
        for ds_id, (scene_id, scene) in enumerate(zip(data.scene_ids, data, strict=True), start=1):
            rows, ids = tracknpred_rows(scene, ds_id)
            units.add(scene.units)
            rates.add(round(1.0 / scene.dt, 6))
            scenes[str(ds_id)] = {"scene_id": scene_id, "units": scene.units, "dt": scene.dt}
            folder = tmp / f"SIM{ds_id}"
            folder.mkdir()
            # float32 columns print as their shortest exact repr ("1.41", not "1.40999997").
            table_df = pd.DataFrame({k: rows[:, j].astype(np.int64) for j, k in enumerate(("ds", "id", "frame"))})
            table_df["x"], table_df["y"] = rows[:, 3].astype(np.float32), rows[:, 4].astype(np.float32)
            table_df.to_csv(folder / TRACKNPRED_FILE, header=False, index=False, lineterminator="\n")
            table.writerows([ds_id, i, scene_id, *rest] for i, *rest in ids)
        (tmp / "index.csv").write_text(index.getvalue())
        (tmp / EXPORT_INFO).write_text(json.dumps({"format": "tracknpred", "scenes": scenes}, indent=1,
                                                  sort_keys=True) + "\n")
        (tmp / "README.txt").write_text(_readme(len(data), units, rates))
    return out


EXPORTERS = {"tracknpred": export_tracknpred}


def export_command(args: argparse.Namespace) -> int:
    """`simharness export FORMAT DIR --out OUT`."""
    fmt = args.format.strip().lower()
    if fmt not in EXPORTERS:
        raise UserError(f"unknown export format {args.format!r}; expected one of {', '.join(EXPORTERS)}")
    out = EXPORTERS[fmt](args.data, args.out)
    print(f"exported {args.data} as {fmt} -> {out}")
    return 0
