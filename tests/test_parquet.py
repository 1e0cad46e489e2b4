"""Parquet data sets: exact round trip, plain readability, atomic writes, clear errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import make_scene

from simharness.errors import UserError
from simharness.io.parquet import (
    BASE_COLUMNS,
    MANIFEST,
    SCHEMA_VERSION,
    Dataset,
    read_scene,
    write_dataset,
    write_scene,
)
from simharness.scene import AgentType, Scene


def zero_invalid(scene: Scene) -> Scene:
    """What a shard can hold: invalid entries as zeros (simulators emit them so anyway)."""
    v = scene.valid
    return scene.replace(xy=scene.xy * v[..., None], heading=scene.heading * v, speed=scene.speed * v,
                         extra={k: a * v for k, a in scene.extra.items()})


def rich_scene(seed: int = 0) -> Scene:
    """Scene with extras, events, road, an agent never valid, and non-trivial frame0."""
    s = make_scene(num_agents=6, num_frames=15, seed=seed)
    rng = np.random.default_rng(seed)
    valid = s.valid.copy()
    valid[5] = False  # an agent without any valid frame must keep its row
    valid[2, 7:] = False
    meta = {"source": "test", "seed": seed, "scenario": "unit", "units": "m",
            "events": [{"kind": "collision", "t": 0.4, "agent_id": "a1", "other_id": "a2", "detail": "x"}],
            "road": {"drivable": [[[0.0, -5.0], [100.0, -5.0], [100.0, 5.0], [0.0, 5.0]]]}}
    s = s.replace(valid=valid, frame0=30, extra={"lateral_offset": rng.normal(size=(6, 15)),
                                                 "sim_heading": rng.normal(size=(6, 15))}, meta=meta)
    return zero_invalid(s)


def test_round_trip_is_exact(tmp_path: Path) -> None:
    scene = rich_scene()
    rows = write_scene(scene, tmp_path / "s.parquet", "s0")
    assert rows == int(scene.valid.sum())
    back = read_scene(tmp_path / "s.parquet")
    assert back.equals(scene, meta=True)
    assert back.agent_id.tolist() == scene.agent_id.tolist() and back.frame0 == 30 and back.ego == scene.ego


def test_round_trip_of_an_empty_scene(tmp_path: Path) -> None:
    scene = Scene.empty(dt=0.2, num_frames=4, meta={"note": "nobody"})
    assert write_scene(scene, tmp_path / "e.parquet", "e") == 0
    assert read_scene(tmp_path / "e.parquet").equals(scene, meta=True)


def test_pandas_and_pyarrow_open_a_shard_as_is(tmp_path: Path) -> None:
    scene = rich_scene()
    write_scene(scene, tmp_path / "s.parquet", "s0")
    df = pd.read_parquet(tmp_path / "s.parquet")
    assert list(df.columns) == [*BASE_COLUMNS, "lateral_offset", "sim_heading"]
    assert len(df) == scene.valid.sum()
    # rows sorted by (frame, agent row); agent_type a categorical of lowercase names
    assert (np.diff(df["frame"].to_numpy()) >= 0).all()
    assert set(df["agent_type"].astype(str)) <= {t.label for t in AgentType}
    assert df["agent_type"].cat.categories.tolist()[:3] == ["car", "bus", "truck"]
    assert df["is_ego"].sum() == scene.valid[scene.ego].sum()
    first = df[df["frame"] == 30]
    rows = np.flatnonzero(scene.valid[:, 0])
    np.testing.assert_array_equal(first["agent_id"].to_numpy(dtype=str), scene.agent_id[rows])
    np.testing.assert_array_equal(first["x"].to_numpy(), scene.xy[rows, 0, 0])
    table = pq.read_table(tmp_path / "s.parquet")
    assert str(table.schema.field("x").type) == "float"
    assert str(table.schema.field("lateral_offset").type) == "float"
    assert b"simharness" in table.schema.metadata


def test_same_scene_gives_identical_bytes(tmp_path: Path) -> None:
    write_scene(rich_scene(0), tmp_path / "a.parquet", "s")
    write_scene(rich_scene(0), tmp_path / "b.parquet", "s")
    write_scene(rich_scene(1), tmp_path / "c.parquet", "s")
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()
    assert (tmp_path / "a.parquet").read_bytes() != (tmp_path / "c.parquet").read_bytes()


def test_write_dataset_and_read_it_back(tmp_path: Path) -> None:
    scenes = [rich_scene(i).replace(meta={**rich_scene(i).meta, "scene_id": f"ep-{i}"}) for i in range(3)]
    out = write_dataset(scenes, tmp_path / "ds", {"source": "unit test", "seeds": [0, 1, 2]})
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "ep-0.parquet", "ep-1.parquet", "ep-2.parquet"]
    ds = Dataset(out)
    assert len(ds) == 3 and ds.scene_ids == ["ep-0", "ep-1", "ep-2"]
    assert ds.manifest["schema_version"] == SCHEMA_VERSION and ds.info["seeds"] == [0, 1, 2]
    assert ds.manifest["rows"] == sum(int(s.valid.sum()) for s in scenes)
    assert {"python", "numpy", "pyarrow", "sumo", "highway-env", "simharness"} <= set(ds.manifest["versions"])
    for a, b in zip(ds, scenes, strict=True):
        assert a.equals(b, meta=True)
    assert ds.scene("ep-1").equals(scenes[1]) and ds.scene(-1).equals(scenes[2])
    assert ds.road is not None and ds.road.bounds() == (0.0, -5.0, 100.0, 5.0)
    # the same scenes again give the same manifest, byte for byte
    again = write_dataset(scenes, tmp_path / "ds2", {"source": "unit test", "seeds": [0, 1, 2]})
    assert (again / MANIFEST).read_bytes() == (out / MANIFEST).read_bytes()
    # a non-empty folder is never silently overwritten
    with pytest.raises(UserError, match="not empty"):
        write_dataset(scenes, out, {})
    write_dataset(scenes[:1], out, {}, overwrite=True)
    assert len(Dataset(out)) == 1 and not list(tmp_path.glob(".tmp-*"))


def test_failed_write_dataset_leaves_nothing(tmp_path: Path) -> None:
    def scenes():
        yield rich_scene(0)
        raise RuntimeError("source broke")

    with pytest.raises(RuntimeError):
        write_dataset(scenes(), tmp_path / "ds", {})
    assert list(tmp_path.iterdir()) == []


def test_dataset_errors_are_one_clear_line(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="not found"):
        Dataset(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="_manifest.json: missing"):
        Dataset(tmp_path / "empty")
    out = write_dataset([rich_scene(0), rich_scene(1)], tmp_path / "ds", {})
    manifest = json.loads((out / MANIFEST).read_text())
    manifest["schema_version"] = 99
    (out / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(UserError, match="schema_version"):
        Dataset(out)
    manifest["schema_version"] = SCHEMA_VERSION
    (out / MANIFEST).write_text(json.dumps(manifest))
    shard = out / "scene-000001.parquet"
    shard.write_bytes(shard.read_bytes()[: shard.stat().st_size // 2])
    with pytest.raises(UserError, match="scene-000001.parquet: damaged shard: .* bytes"):
        Dataset(out)
    shard.unlink()
    with pytest.raises(UserError, match="scene-000001.parquet: shard listed in _manifest.json is missing"):
        Dataset(out)


def test_cli_names_a_corrupt_shard_and_exits_2(tmp_path: Path) -> None:
    out = write_dataset([rich_scene(0)], tmp_path / "ds", {})
    shard = out / "scene-000000.parquet"
    data = bytearray(shard.read_bytes())
    data[-12:-8] = b"\xff\xff\xff\x7f"  # footer length past the file start
    shard.write_bytes(bytes(data))
    proc = subprocess.run([sys.executable, "-m", "simharness", "stats", str(out)], capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "scene-000000.parquet" in lines[0] and "damaged" in lines[0]
    proc = subprocess.run([sys.executable, "-m", "simharness", "stats", str(tmp_path)], capture_output=True,
                          text=True)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "_manifest.json: missing" in proc.stderr


def test_columns_carry_units_and_t_is_exact(tmp_path: Path) -> None:
    from simharness.io.parquet import COLUMN_DOCS

    scene = make_scene(num_frames=40, dt=0.1)
    write_scene(scene, tmp_path / "s.parquet", "s")
    schema = pq.read_schema(tmp_path / "s.parquet")
    for name in BASE_COLUMNS:
        meta = schema.field(name).metadata
        assert meta[b"unit"].decode() == COLUMN_DOCS[name][0] and meta[b"description"], name
    assert schema.field("x").metadata[b"unit"] == b"m" and schema.field("speed").metadata[b"unit"] == b"m/s"
    t = pq.read_table(tmp_path / "s.parquet").column("t").to_pylist()
    assert 0.6 in t and all(repr(v) == repr(round(v, 9)) for v in t)  # 0.6, never 0.6000000000000001
    doc = (Path(__file__).resolve().parent.parent / "docs" / "dataset.md").read_text()
    assert all(f"`{name}`" in doc for name in (*BASE_COLUMNS, "lateral_offset"))


def test_a_shard_shows_damage_by_its_own_bytes(tmp_path: Path) -> None:
    from simharness.io.parquet import shard_damage

    path = tmp_path / "scene-000000.parquet"
    write_scene(make_scene(num_agents=8, num_frames=60), path, "scene-000000")
    assert shard_damage(path) is None
    data = bytearray(path.read_bytes())
    data[300:340] = bytes(40)  # a page's bytes zeroed: its checksum fails, whatever a manifest says
    path.write_bytes(bytes(data))
    assert shard_damage(path) is not None
    path.write_bytes(bytes(data[:500]))
    assert "corrupt or unreadable" in shard_damage(path)
