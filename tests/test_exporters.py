"""TrackNPred export: import -> Parquet -> Scene -> export, and the layout the authors' code needs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from simharness.errors import UserError
from simharness.io.exporters import export_tracknpred, track_runs
from simharness.io.importers import import_tracknpred
from simharness.io.parquet import Dataset, write_dataset
from tests.conftest import make_scene

ETH = Path(__file__).resolve().parents[2] / "shared" / "data" / "eth_ucy"


def test_round_trip_eth_through_parquet_and_tracknpred(tmp_path):
    data, out = tmp_path / "eth", tmp_path / "tnp"
    for cmd in (["import", "eth-ucy", str(ETH), "--out", str(data)], ["export", "tracknpred", str(data), "--out",
                                                                         str(out)]):
        r = subprocess.run([sys.executable, "-m", "simharness", *cmd], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    scenes = list(Dataset(data))
    index = pd.read_csv(out / "index.csv", dtype={"agent_id": str})
    for ds_id, scene in enumerate(scenes, start=1):
        rows = np.loadtxt(out / f"SIM{ds_id}" / "formatted_hypo.txt", delimiter=",")
        assert rows.shape == (int(scene.valid.sum()), 5) and (rows[:, 0] == ds_id).all()
        ids = rows[:, 1].astype(int)
        assert ids.min() == 1 and set(ids) == set(range(1, ids.max() + 1))
        for i in np.unique(ids):  # consecutive frames per id
            assert (np.diff(rows[ids == i, 2]) == 1).all()
        # Every exported row is the scene's position of the mapped agent at that frame.
        ix = index[index.dsId == ds_id].set_index("id")
        agent_row = {a: k for k, a in enumerate(scene.agent_id)}
        r = np.array([agent_row[a] for a in ix.loc[ids, "agent_id"]])
        np.testing.assert_array_equal(rows[:, 3:5].astype(np.float32), scene.xy[r, rows[:, 2].astype(int)])
        # And our own importer reads it back with the units and rate recorded by the export.
        (back,) = import_tracknpred([out / f"SIM{ds_id}" / "formatted_hypo.txt"])
        assert back.units == "m" and back.dt == scene.dt and int(back.valid.sum()) == int(scene.valid.sum())
        assert np.array_equal(np.sort(back.xy[back.valid], axis=0), np.sort(scene.xy[scene.valid], axis=0))
    assert "t_h=8, t_f=12" in (out / "README.txt").read_text()  # 3 s / 5 s at 2.5 Hz


def test_gaps_split_into_ids_and_out_is_refused_when_full(tmp_path):
    scene = make_scene(num_agents=2, num_frames=8)
    valid = scene.valid.copy()
    valid[1, 3:5] = False  # agent a1 vanishes for two frames
    write_dataset([scene.replace(valid=valid)], tmp_path / "d", {"source": "test"})
    out = export_tracknpred(tmp_path / "d", tmp_path / "x")
    rows = np.loadtxt(out / "SIM1" / "formatted_hypo.txt", delimiter=",")
    assert sorted(set(rows[:, 1].astype(int))) == [1, 2, 3]  # a0 (frames 2-7), a1 (0-2), a1 (5-7)
    index = pd.read_csv(out / "index.csv")
    assert index.agent_id.tolist() == ["a0", "a1", "a1"] and index.first_frame.tolist() == [2, 0, 5]
    row, start, stop = track_runs(valid)
    assert row.tolist() == [0, 1, 1] and start.tolist() == [2, 0, 5] and stop.tolist() == [8, 3, 8]
    with pytest.raises(UserError, match="exists and is not empty"):
        export_tracknpred(tmp_path / "d", tmp_path / "x")
    with pytest.raises(UserError, match="data set folder not found"):
        export_tracknpred(tmp_path / "nope", tmp_path / "y")
    assert not (tmp_path / "y").exists()
