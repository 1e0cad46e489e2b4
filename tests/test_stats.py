"""Data set figures against hand-computed answers on small written data sets."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simharness.io.parquet import write_dataset
from simharness.scene import AgentType, Scene
from simharness.sim.base import RoadGeometry
from simharness.stats import dataset_stats, format_table, neighbours_within, road_length_m, types_per_frame

A = AgentType


def known_scene() -> Scene:
    """4 agents, 2 frames, on a 200 m x 10 m road.

    frame 0: car at x=0, bus at x=30, pedestrian at x=100, motorcycle overlapping the car (x=1, y=0.5)
    frame 1: the motorcycle has left; others moved 1 m.
    """
    xy = np.zeros((4, 2, 2), np.float32)
    xy[:, 0] = [[0, 0], [30, 0], [100, 0], [1, 0.5]]
    xy[:3, 1] = xy[:3, 0] + [1, 0]
    valid = np.array([[1, 1], [1, 1], [1, 1], [1, 0]], bool)
    speed = np.array([[5, 5], [10, 10], [1, 1], [7, 0]], np.float32)
    types = [A.CAR, A.BUS, A.PEDESTRIAN, A.MOTORCYCLE]
    road = RoadGeometry(drivable=(np.array([[0, -5], [200, -5], [200, 5], [0, 5]], float),))
    return Scene(
        xy=xy, heading=np.zeros((4, 2)), speed=speed, valid=valid, agent_id=["c", "b", "p", "m"], agent_type=types,
        length=[4.0, 12.0, 0.5, 2.0], width=[1.8, 2.5, 0.5, 0.8], dt=0.5,
        extra={"lateral_offset": xy[..., 1]},
        meta={"events": [{"kind": "collision", "t": 0.0, "agent_id": "c", "other_id": "m"},
                         {"kind": "teleport", "t": 0.5, "agent_id": "b"}], "road": road.to_dict()},
    )


def test_neighbours_and_types_per_frame() -> None:
    s = known_scene()
    n = neighbours_within(s.xy, s.valid)
    # frame 0: car has bus (30 m) and motorcycle; bus has car and motorcycle (29.0 m); pedestrian none
    np.testing.assert_array_equal(n[:, 0], [2, 2, 0, 2])
    np.testing.assert_array_equal(n[:, 1], [1, 1, 0, 0])
    counts = types_per_frame(s.agent_type, s.valid)
    assert counts.shape == (len(AgentType), 2)
    assert counts[:, 0].sum() == 4 and counts[A.MOTORCYCLE, 1] == 0 and counts[A.BUS].tolist() == [1, 1]


def test_road_length_from_spec_or_geometry() -> None:
    road = RoadGeometry(drivable=(np.array([[0, -5], [200, -5], [200, 5], [0, 5]], float),))
    assert road_length_m(road, None) == pytest.approx(200.0)
    assert road_length_m(road, {"road": {"layout": "intersection", "length": 150.0}}) == 600.0
    assert road_length_m(None, None) is None


def test_dataset_stats_against_hand_counts(tmp_path: Path) -> None:
    out = write_dataset([known_scene()], tmp_path / "ds", {"source": "unit"})
    s = dataset_stats(out)
    assert s["frames"] == 2 and s["agent_frames"] == 7 and s["agents"] == 4
    assert s["agents_per_frame"] == pytest.approx(3.5)
    assert s["agents_per_frame_by_type"]["motorcycle"] == pytest.approx(0.5)
    assert s["agents_per_frame_by_type"]["car"] == pytest.approx(1.0)
    assert s["distinct_types"] == 4 and s["distinct_types_per_frame"] == {"min": 3, "mean": 3.5}
    assert s["agents_within_50m"] == pytest.approx((2 + 2 + 0 + 2 + 1 + 1 + 0) / 7, abs=1e-4)
    assert s["road_length_m"] == pytest.approx(200.0)
    assert s["density_per_km"] == pytest.approx(3.5 / 0.2)
    assert s["speed_by_type"]["motorcycle"] == {"mean": 7.0, "std": 0.0}
    assert s["lateral_offset_by_type"]["motorcycle"]["p95"] == pytest.approx(0.5)
    assert s["lateral_source"] == "lateral_offset"
    c = s["collisions"]
    assert c["simulator"] == 1 and c["box_overlap"] == 1 and c["box_overlap_by_kind"]["vehicle-vehicle"] == 1
    # 7 agent-frames of 0.5 s = 3.5 s = 1/17.14 agent-minutes
    assert c["rate_per_1000_agent_min"]["box_overlap"] == pytest.approx(1000 / (3.5 / 60), rel=1e-4)
    assert s["teleports"] == 1
    json.dumps(s)  # JSON-ready
    table = format_table(s)
    assert "Density/km" in table and "motorcycle" in table


def test_stats_cli_json_and_figure(tmp_path: Path) -> None:
    out = write_dataset([known_scene()], tmp_path / "ds", {"source": "unit"})
    proc = subprocess.run([sys.executable, "-m", "simharness", "stats", str(out), "--json", "--figure",
                           str(tmp_path / "f.png")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["frames"] == 2 and s["distinct_types"] == 4 and s["teleports"] == 1
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"
