"""Importers on the real shared samples (counts, rates, units, types, hand-checked rows) and on broken copies."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from simharness.errors import UserError
from simharness.io import importers as im
from simharness.io.parquet import Dataset
from simharness.scene import AgentType, Scene

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ETH = DATA / "eth_ucy"
TRAF = DATA / "traf"
APOLLO = DATA / "apolloscape" / "prediction_gt_sample.txt"
CR = DATA / "commonroad_ngsim"
AV2 = DATA / "av2" / "scenario_0a1e6f0a-1817-4a98-b02e-db8c9327d151.parquet"
TNP = DATA / "tracknpred"


def at(scene: Scene, agent: str, column: int) -> np.ndarray:
    row = int(np.flatnonzero(scene.agent_id == agent)[0])
    assert scene.valid[row, column]
    return scene.xy[row, column]


# ---------------------------------------------------------------------- each format on its sample
def test_eth_ucy_counts_rows_and_gaps():
    hotel, zara = im.import_eth_ucy([ETH / "biwi_hotel.txt", ETH / "crowds_zara01.txt"])
    assert (hotel.num_agents, hotel.num_frames, int(hotel.valid.sum())) == (389, 1807, 6543)
    assert (zara.num_agents, int(zara.valid.sum())) == (148, 5153)
    assert hotel.dt == zara.dt == 0.4 and hotel.units == "m" and hotel.meta["frame_rate_hz"] == 2.5
    assert hotel.meta["source_frame_step"] == 10 and hotel.meta["source"] == "biwi_hotel.txt"
    assert (hotel.agent_type == AgentType.PEDESTRIAN).all()
    # Line 1 "0 1.0 1.41 -5.68"; line 1000 "2940 82.0 3.43 -7.29"; zara line 2000 "3730.0 58.0 10.2351.. 5.9557..".
    np.testing.assert_allclose(at(hotel, "1", 0), [1.41, -5.68], atol=1e-6)
    np.testing.assert_allclose(at(hotel, "82", 294), [3.43, -7.29], atol=1e-6)
    np.testing.assert_allclose(at(zara, "58", 373), [10.2351287462, 5.95575530185], atol=1e-5)
    # Frames missing from the file stay empty columns: 1168 distinct annotated frames of 1807.
    assert int(hotel.valid.any(0).sum()) == 1168
    # Heading and speed from finite differences: speed is the step length over 0.4 s.
    row = int(np.flatnonzero(hotel.agent_id == "1")[0])
    step = np.linalg.norm(hotel.xy[row, 1] - hotel.xy[row, 0]) / 0.4
    assert hotel.speed[row, 0] == pytest.approx(step, rel=1e-5)


def test_traf_pixels_classes_and_centres():
    t11, t12 = im.import_traf([TRAF / "TRAF11_gt.txt", TRAF / "TRAF12_gt.txt"])
    assert (t11.num_agents, t11.num_frames, int(t11.valid.sum())) == (88, 1024, 18954)
    assert (t12.num_agents, t12.num_frames) == (152, 956)
    assert t11.units == "px" and t11.meta["units"] == "px" and t11.dt == pytest.approx(0.05)
    counts = np.bincount(t11.agent_type, minlength=len(AgentType))
    assert counts[AgentType.CAR] == 33 and counts[AgentType.MOTORCYCLE] == 20 and counts[AgentType.RICKSHAW] == 8
    assert counts[AgentType.PEDESTRIAN] == 12  # 11 "ped" and the one "man0"
    assert t11.meta["dropped_unlabelled"] == 2 and t12.meta["dropped_duplicates"] == 27
    # Line 1: "0,10,638,402,200,231,rickshaw0,...": centre = top-left + half the box.
    np.testing.assert_allclose(at(t11, "rickshaw0", 0), [638 + 100, 402 + 115.5])
    # TRAF12 line 500: "499,16,365,431,97,161,scooter0,...".
    np.testing.assert_allclose(at(t12, "scooter0", 499), [365 + 48.5, 431 + 80.5])
    r = int(np.flatnonzero(t12.agent_id == "scooter0")[0])
    assert t12.extra["box_w"][r, 499] == 97 and t12.extra["box_h"][r, 499] == 161
    assert im.traf_class("sccoter3") == AgentType.SCOOTER and im.traf_class("rick2") == AgentType.RICKSHAW
    assert im.traf_class("cycle0") == AgentType.BICYCLE and im.traf_class("bike7") == AgentType.MOTORCYCLE


def test_apolloscape_chunks_and_types():
    scenes = im.import_apolloscape([APOLLO])
    assert len(scenes) == 33 and all(s.dt == 0.5 and s.units == "m" for s in scenes)
    assert sum(int(s.valid.sum()) for s in scenes) == 3000
    first = scenes[0]
    assert first.meta["scene_id"] == "prediction_gt_sample-000206" and first.num_frames == 6
    # Line 4: "206 10007 4 368.164 133.796" -> a bicyclist at the chunk's first frame.
    np.testing.assert_allclose(at(first, "10007", 0), [368.164, 133.796], atol=1e-4)
    assert first.agent_type[first.agent_id == "10007"][0] == AgentType.BICYCLE
    assert first.frame0 == 206


def test_commonroad_sizes_headings_road():
    a, b = im.import_commonroad(sorted(CR.glob("*.xml")))
    assert (a.num_agents, a.num_frames, int(a.valid.sum())) == (44, 81, 2840)
    assert b.num_agents == 32 and a.dt == pytest.approx(0.1)
    r = int(np.flatnonzero(a.agent_id == "500")[0])
    assert (a.length[r], a.width[r]) == pytest.approx((6.096, 2.5603))
    np.testing.assert_allclose(a.xy[r, 0], [87.4187, -91.9901], atol=1e-4)
    np.testing.assert_allclose(a.xy[r, 1], [88.4554, -92.8887], atol=1e-4)
    assert a.heading[r, 0] == pytest.approx(-0.71018) and a.speed[r, 0] == pytest.approx(13.3167)
    assert len(a.meta["road"]["drivable"]) == 12 and a.meta["planning_problem"]["velocity"] == pytest.approx(9.336)


def test_argoverse2_types_ego_focal():
    (s,) = im.import_argoverse2([AV2])
    df = pq.read_table(AV2).to_pandas()
    assert (s.num_agents, s.num_frames, int(s.valid.sum())) == (58, 110, len(df))
    assert s.agent_id[s.ego] == "AV" and s.meta["focal_agent"] == "138951"
    assert "138951" in s.meta["scored_agents"]
    counts = np.bincount(s.agent_type, minlength=len(AgentType))
    assert counts[AgentType.CAR] == 32 and counts[AgentType.PEDESTRIAN] == 12
    row = df[(df.track_id == "138951") & (df.timestep == 50)].iloc[0]
    r = int(np.flatnonzero(s.agent_id == "138951")[0])
    np.testing.assert_allclose(s.xy[r, 50], [row.position_x, row.position_y], rtol=1e-6)
    assert s.heading[r, 50] == pytest.approx(row.heading, abs=1e-6)
    assert s.extra["observed"][r, 50] == float(row.observed)


def test_tracknpred_text_and_pickle_refusal():
    (txt,) = im.import_tracknpred([TNP / "TrainSet.txt"])
    assert (txt.num_agents, int(txt.valid.sum()), txt.units) == (98, 5947, "px")
    assert txt.meta["dataset_id"] == 12
    np.testing.assert_allclose(at(txt, "1", 0), [568.04, 406.16], atol=1e-4)  # line 1: frame 2 = column 0
    np.testing.assert_allclose(at(txt, "1", 16), [488.74, 402.05], atol=1e-4)  # line 100: frame 18
    with pytest.raises(UserError, match=r"TrainSet.npy: a pickled NumPy object array.*--allow-pickle"):
        im.import_tracknpred([TNP / "TrainSet.npy"])
    (npy,) = im.import_tracknpred([TNP / "TrainSet.npy"], allow_pickle=True)
    assert npy.equals(txt)


def test_motion_from_positions_line_and_stop():
    xy = np.zeros((1, 5, 2))
    xy[0, :3, 0] = [0.0, 1.0, 2.0]  # moving along +x, then standing at x = 2
    xy[0, :3, 1] = [0.0, 1.0, 2.0]
    xy[0, 3:] = xy[0, 2]
    valid = np.ones((1, 5), bool)
    heading, speed = im.motion_from_positions(xy, valid, dt=0.5)
    np.testing.assert_allclose(heading[0], np.pi / 4, atol=1e-6)  # standing keeps the last heading
    np.testing.assert_allclose(speed[0, :2], np.sqrt(2) / 0.5, rtol=1e-6)
    assert speed[0, -1] == 0


# ---------------------------------------------------------------------- the command
def test_import_command_writes_a_dataset(tmp_path):
    out = tmp_path / "traf"
    r = subprocess.run([sys.executable, "-m", "simharness", "import", "traf", str(TRAF / "TRAF11_gt.txt"),
                        str(TRAF / "TRAF12_gt.txt"), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "units px" in r.stdout and "2 scene(s)" in r.stdout
    data = Dataset(out)
    assert data.scene_ids == ["TRAF11_gt", "TRAF12_gt"]
    assert data.manifest["info"]["source"]["format"] == "traf"
    scene = data.scene("TRAF11_gt")
    assert scene.units == "px" and scene.equals(im.import_traf([TRAF / "TRAF11_gt.txt"])[0])
    assert len(pd.read_parquet(out / "TRAF11_gt.parquet")) == 18954


def test_import_command_refuses_pickle_and_writes_nothing(tmp_path):
    out = tmp_path / "tnp"
    r = subprocess.run([sys.executable, "-m", "simharness", "import", "tracknpred", str(TNP / "TrainSet.npy"),
                        "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 2 and "pickle" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() and not list(tmp_path.iterdir())


# ---------------------------------------------------------------------- broken copies
def _copy_with(tmp_path: Path, src: Path, lineno: int, text: str) -> Path:
    lines = src.read_text().splitlines()
    lines[lineno - 1] = text
    dst = tmp_path / src.name
    dst.write_text("\n".join(lines) + "\n")
    return dst


@pytest.mark.parametrize("fmt, src, line, text, expect", [
    ("eth-ucy", ETH / "biwi_hotel.txt", 3, "0\t3.0\tabc\t-4.59", r"biwi_hotel.txt:3: .*'abc'"),
    ("eth-ucy", ETH / "biwi_hotel.txt", 5, "0\t5.0\t1\t2\t7", r"biwi_hotel.txt:5: expected 4 fields"),
    ("eth-ucy", ETH / "biwi_hotel.txt", 7, "3\t99\t1\t2", r"biwi_hotel.txt:7: frame 3 is not on the 10-frame grid"),
    ("traf", TRAF / "TRAF11_gt.txt", 2, "1,10,640,402", r"TRAF11_gt.txt:2: says 10 agents"),
    ("traf", TRAF / "TRAF11_gt.txt", 4, "3,1,1,x,3,4,car9", r"TRAF11_gt.txt:4: expected numbers .*'x'"),
    ("apolloscape", APOLLO, 4, "206 10007 9 368.164 133.796", r"prediction_gt_sample.txt:4: object type 9"),
    ("apolloscape", APOLLO, 6, "206 10001 1 1.0 2.0", r"prediction_gt_sample.txt:6: agent '10001' appears twice"),
    ("tracknpred", TNP / "TrainSet.txt", 9, "2\t1\t5.0", r"TrainSet.txt:9: expected 5 numbers"),
])
def test_malformed_text_names_file_and_line(tmp_path, fmt, src, line, text, expect):
    broken = _copy_with(tmp_path, src, line, text)
    with pytest.raises(UserError, match=expect):
        list(im.import_scenes(fmt, [broken]))


def test_malformed_commonroad(tmp_path):
    src = CR / "USA_US101-11_1_T-1.xml"
    lines = src.read_text().splitlines()
    (tmp_path / "cut.xml").write_text("\n".join(lines[:300]))  # truncated mid-document
    with pytest.raises(UserError, match=r"cut.xml:\d+: not well-formed XML"):
        im.import_commonroad([tmp_path / "cut.xml"])
    i = next(k for k, ln in enumerate(lines) if "<trajectory>" in ln)
    j = next(k for k in range(i, len(lines)) if "<position>" in lines[k])
    broken = lines[:j] + lines[j + 6:]  # drop one state's <position>..</position>
    (tmp_path / "nopos.xml").write_text("\n".join(broken))
    with pytest.raises(UserError, match=rf"nopos.xml:{j}: <state> lacks <position><point>"):
        im.import_commonroad([tmp_path / "nopos.xml"])


def test_malformed_argoverse2(tmp_path):
    table = pq.read_table(AV2)
    pq.write_table(table.drop(["heading"]), tmp_path / "nohead.parquet")
    with pytest.raises(UserError, match=r"nohead.parquet: missing column 'heading'"):
        im.import_argoverse2([tmp_path / "nohead.parquet"])
    (tmp_path / "bad.parquet").write_bytes(AV2.read_bytes()[:5000])
    with pytest.raises(UserError, match=r"bad.parquet: not a readable Parquet file"):
        im.import_argoverse2([tmp_path / "bad.parquet"])


def test_malformed_file_through_cli_writes_nothing(tmp_path):
    broken = _copy_with(tmp_path, ETH / "crowds_zara01.txt", 12, "oops")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "simharness", "import", "eth-ucy", str(broken), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "crowds_zara01.txt:12:" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["crowds_zara01.txt"]
    r = subprocess.run([sys.executable, "-m", "simharness", "import", "nuscenes", str(broken), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "unknown import format 'nuscenes'" in r.stderr
