"""Data sets that never lie : each case a hostile user tried, kept fixed.

Shards checked against the manifest (size, sha256) on read and on resume; caches keyed on shard content;
NaN and infinities refused; concurrent writers safe; one output-folder rule; every error one line, exit 2.
Everything runs the real thing: SUMO, Parquet, torch, the CLI in-process or as a subprocess.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
import typing
from pathlib import Path

import duckdb
import pandas as pd
import polars as pl
import pyarrow.dataset as pds
import pytest
import torch
from _predictor_data import flow_scene, write_flow_dataset

from predictor.checkpoint import load_checkpoint, save_checkpoint
from predictor.train import open_data
from simharness.cli import MAX_SEEDS, main, parse_seeds
from simharness.errors import UserError
from simharness.io.folders import prepare_output, writer_lock
from simharness.io.parquet import (
    LEGACY_MANIFEST,
    MANIFEST,
    Dataset,
    build_manifest,
    file_sha256,
    read_manifest,
    shard_entry,
    write_dataset,
    write_manifest,
    write_scene,
)
from simharness.scenario import ScenarioSpec, load_scenario

TINY = """name = "tiny"
backend = "sumo"
duration = 4.0
warmup = 5.0
[road]
length = 200.0
[demand]
car = 1800
motorcycle = 900
"""
SHIPPED_WEIGHTS = Path(__file__).resolve().parent.parent / "predictor" / "weights"
DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def one_error_line(capsys: pytest.CaptureFixture[str], *needles: str) -> str:
    text = capsys.readouterr().err.replace("\r", "\n").replace("simharness: ", "\nsimharness: ")
    err = [line for line in text.splitlines() if line.strip() and "%|" not in line]  # tqdm bars
    assert len(err) == 1 and "Traceback" not in err[0], err
    for n in needles:
        assert n in err[0], err[0]
    return err[0]


def data_files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.name not in ("_runs.jsonl", "_lock")}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> tuple[Path, Path]:
    """(scenario file, a SUMO data set of seeds 0-1, generated through the CLI)."""
    folder = tmp_path_factory.mktemp("tiny")
    scenario = folder / "tiny.toml"
    scenario.write_text(TINY)
    out = folder / "ds"
    assert main(["generate", str(scenario), "--seeds", "0-1", "--out", str(out), "--workers", "1"]) == 0
    return scenario, out


# ---------------------------------------------------------------------- shards checked on read and resume
def test_manifest_lists_size_and_hash_and_is_skipped_by_readers(tiny) -> None:
    _, out = tiny
    names = sorted(p.name for p in out.iterdir())
    assert names == ["_lock", MANIFEST, "_runs.jsonl", "scene-000000.parquet", "scene-000001.parquet"]
    manifest = read_manifest(out)
    for e in manifest["scenes"]:
        shard = out / e["file"]
        assert e["bytes"] == shard.stat().st_size and e["sha256"] == file_sha256(shard)
    rows = manifest["rows"]
    # the folder opens as one table in every common reader
    assert len(pd.read_parquet(out)) == rows
    assert pds.dataset(out).count_rows() == rows
    assert duckdb.sql(f"select count(*) from read_parquet('{out}/*.parquet')").fetchall() == [(rows,)]
    assert pl.scan_parquet(out, hidden_file_prefix="_").collect().height == rows
    assert pl.read_parquet(out / "*.parquet").height == rows


def test_old_manifest_name_is_still_read_and_replaced_on_resume(tiny, tmp_path: Path, capsys) -> None:
    scenario, ref = tiny
    out = tmp_path / "old"
    shutil.copytree(ref, out)
    (out / MANIFEST).rename(out / LEGACY_MANIFEST)
    (out / "_runs.jsonl").rename(out / "runs.jsonl")
    assert len(Dataset(out)) == 2
    assert main(["generate", str(scenario), "--seeds", "0-1", "--out", str(out), "--workers", "1"]) == 0
    assert not (out / LEGACY_MANIFEST).exists() and not (out / "runs.jsonl").exists()
    assert (out / MANIFEST).is_file() and (out / "_runs.jsonl").read_text().count("\n") == 2


def test_truncated_listed_shard_is_refused_on_read_and_remade_on_resume(tiny, tmp_path: Path, capsys) -> None:
    scenario, ref = tiny
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    shard = out / "scene-000001.parquet"
    shard.write_bytes(shard.read_bytes()[:1000])
    assert main(["stats", str(out)]) == 2
    one_error_line(capsys, "scene-000001.parquet", "damaged shard", "1000 bytes")
    assert main(["generate", str(scenario), "--seeds", "0-1", "--out", str(out), "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "scene-000001.parquet: damaged" in captured.err and "remade in this run" in captured.err
    assert "1 scenes generated, 1 already complete" in captured.out
    assert data_files(out) == data_files(ref)


def test_shard_overwritten_in_place_is_refused_on_read_and_remade_on_resume(tiny, tmp_path: Path, capsys) -> None:
    scenario, ref = tiny
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    shard = out / "scene-000000.parquet"
    data = bytearray(shard.read_bytes())
    data[200:4296] = bytes(4096)  # 4 KB of the x/y pages zeroed, size unchanged
    shard.write_bytes(bytes(data))
    with pytest.raises(UserError, match="scene-000000.parquet: damaged shard: content differs"):
        Dataset(out)
    assert main(["generate", str(scenario), "--seeds", "1", "--out", str(out), "--workers", "1"]) == 0
    assert "rerun with --seeds 0 to remake it" in capsys.readouterr().err
    assert len(Dataset(out)) == 1  # the damaged one is gone, not listed
    assert main(["generate", str(scenario), "--seeds", "0-1", "--out", str(out), "--workers", "1"]) == 0
    assert data_files(out) == data_files(ref)


def test_killed_run_shards_are_refused_on_read_then_listed_on_resume(tiny, tmp_path: Path, capsys) -> None:
    scenario, ref = tiny
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    # what a kill -9 between the shards' renames and the manifest refresh leaves: shards, a manifest of none
    write_manifest(out, build_manifest([], read_manifest(out)["info"]))
    assert main(["stats", str(out)]) == 2
    one_error_line(capsys, "shard not listed", "rerun the same `simharness generate`")
    assert main(["generate", str(scenario), "--seeds", "0-1", "--out", str(out), "--workers", "1"]) == 0
    assert "0 scenes generated, 2 already complete" in capsys.readouterr().out
    assert data_files(out) == data_files(ref)


def test_stats_of_an_empty_data_set_is_an_error(tmp_path: Path, capsys) -> None:
    out = write_dataset([], tmp_path / "empty", {"source": "test"})
    assert main(["stats", str(out)]) == 2
    one_error_line(capsys, "lists no scenes")


def test_generate_refuses_a_file_as_out_and_odd_shard_names(tiny, tmp_path: Path, capsys) -> None:
    scenario, _ = tiny
    (tmp_path / "f").write_text("x")
    assert main(["generate", str(scenario), "--out", str(tmp_path / "f")]) == 2
    one_error_line(capsys, "names a file")
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "scene-abc.parquet").write_text("x")
    assert main(["generate", str(scenario), "--out", str(tmp_path / "ds")]) == 2
    one_error_line(capsys, "scene-abc.parquet", "not part of a simharness data set")


# ---------------------------------------------------------------------- concurrent writers
def test_two_generates_into_one_folder_end_with_every_shard_listed(tiny, tmp_path: Path) -> None:
    scenario, _ = tiny
    out = tmp_path / "ds"
    cmd = [sys.executable, "-m", "simharness", "generate", str(scenario), "--out", str(out), "--workers", "1"]
    procs = [subprocess.Popen([*cmd, "--seeds", seeds], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for seeds in ("0-2", "3-4")]
    results = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], results
    # (whether the second waited depends on timing; the lock itself is tested below)
    ds = Dataset(out)
    assert ds.scene_ids == [f"scene-{s:06d}" for s in range(5)] and ds.info["seeds"] == [0, 1, 2, 3, 4]
    assert not list(out.glob(".tmp-*"))


def test_the_writer_lock_is_exclusive_and_dies_with_its_holder(tmp_path: Path) -> None:
    code = ("import sys, time; from simharness.io.folders import writer_lock\n"
            "with writer_lock(sys.argv[1]):\n    print('got', flush=True); time.sleep(float(sys.argv[2]))")
    with writer_lock(tmp_path):
        p = subprocess.Popen([sys.executable, "-c", code, str(tmp_path), "0"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
        with pytest.raises(subprocess.TimeoutExpired):
            p.communicate(timeout=3)  # blocked while this process holds the lock
    out, err = p.communicate(timeout=30)
    assert out == "got\n" and "waiting for another writer" in err
    holder = subprocess.Popen([sys.executable, "-c", code, str(tmp_path), "60"], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline() == "got\n"
    holder.kill()
    holder.wait()
    with writer_lock(tmp_path):  # a killed holder leaves no stale lock
        pass


# ---------------------------------------------------------------------- caches keyed on shard content
def test_warm_cache_is_never_used_for_changed_shards(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("SIMHARNESS_CACHE_DIR", str(tmp_path / "cache"))
    data = write_flow_dataset(tmp_path / "data", scenes=4)
    train = ["train", "--data", str(data), "--model", "traphic-b", "--epochs", "1",
             "--warmup-epochs", "1", "--max-samples", "64", "--batch-size", "32"]
    assert main([*train, "--out", str(tmp_path / "r1")]) == 0
    key = open_data(data)[0]
    shard = data / "scene-000000.parquet"
    raw = bytearray(shard.read_bytes())
    raw[100:4196] = bytes(4096)
    shard.write_bytes(bytes(raw))
    capsys.readouterr()
    assert main([*train, "--out", str(tmp_path / "r2")]) == 2
    one_error_line(capsys, "scene-000000.parquet", "damaged shard")
    assert not (tmp_path / "r2").exists()
    # a legitimate rewrite (new content, manifest updated to match) gets a new key: the cache is rebuilt
    new = flow_scene(99)
    rows = write_scene(new, shard, "scene-000000")
    manifest = read_manifest(data)
    entries = [shard_entry(shard, new, "scene-000000", rows) if e["file"] == shard.name else e
               for e in manifest["scenes"]]
    write_manifest(data, build_manifest(entries, manifest["info"]))
    assert open_data(data)[0] != key
    assert open_data(data)[0] == Dataset(data).content_hash


# ---------------------------------------------------------------------- NaN and infinities
def _float_keys(cls: type = ScenarioSpec, prefix: str = "") -> list[str]:
    hints = typing.get_type_hints(cls)
    keys = []
    for f in dataclasses.fields(cls):
        if f.metadata.get("internal"):
            continue
        h = hints[f.name]
        if dataclasses.is_dataclass(h):
            keys += _float_keys(h, prefix + f.name + ".")
        elif h is float or typing.get_origin(h) is dict:
            keys.append(prefix + f.name + (".car" if typing.get_origin(h) is dict else ""))
    return keys


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_every_float_key_of_a_scenario_refuses_non_finite(tmp_path: Path, value: str) -> None:
    keys = _float_keys()
    assert len(keys) >= 20 and "demand.car" in keys and "duration" in keys
    for key in keys:
        data: dict = {"name": "tiny", "duration": 4.0, "road": {"length": 200.0}, "demand": {"motorcycle": 900}}
        *table, leaf = key.split(".")
        node = data
        for t in table:
            node = node.setdefault(t, {})
        node[leaf] = float(value)
        path = tmp_path / "s.toml"
        path.write_text(_toml(data))
        with pytest.raises(UserError, match=f"key '{key}': expected a finite number"):
            load_scenario(path)


def _toml(data: dict) -> str:
    """Two-level dict -> TOML text; floats by repr, so NaN and infinities come out as TOML's nan, inf, -inf."""
    top = [f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"' for k, v in data.items()
           if not isinstance(v, dict)]
    tables = [f"[{k}]\n" + "\n".join(f"{kk} = {vv!r}" for kk, vv in v.items()) for k, v in data.items()
              if isinstance(v, dict)]
    return "\n".join(top + tables) + "\n"


def test_cli_refuses_non_finite_numbers_and_leaves_nothing(tiny, tmp_path: Path, capsys) -> None:
    scenario, data = tiny
    for argv in (["generate", str(scenario), "--out", str(tmp_path / "g"), "--duration", "nan"],
                 ["generate", str(scenario), "--out", str(tmp_path / "g"), "--duration", "inf"],
                 ["train", "--data", str(data), "--out", str(tmp_path / "t"), "--lr", "nan"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
        assert "expected a finite number" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    spec = load_scenario(scenario)
    with pytest.raises(UserError, match="duration"):
        spec.with_overrides({"duration": float("nan")})
    assert main(["sweep", str(scenario), "--set", "demand_scale=nan", "--out", str(tmp_path / "sw")]) == 2
    assert "key 'demand_scale': expected a finite number, got nan" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_checkpoint_with_nan_weights_is_one_line_and_writes_nothing(tmp_path: Path, capsys) -> None:
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(SHIPPED_WEIGHTS / "traphic.json", run / "config.json")
    state = torch.load(SHIPPED_WEIGHTS / "traphic.pt", weights_only=True)
    name = next(k for k, v in state.items() if v.is_floating_point())
    state[name][0] = float("nan")
    torch.save(state, run / "model.pt")
    with pytest.raises(UserError, match=f"weight '{name}' holds NaN"):
        load_checkpoint(run / "model.pt", run / "config.json")
    data = write_dataset([flow_scene(0)], tmp_path / "data", {"source": "test"})
    assert main(["evaluate", "--data", str(data), "--model", str(run), "--out", str(tmp_path / "ev"),
                 "--split", "all"]) == 2
    one_error_line(capsys, "model.pt", "NaN")
    assert not (tmp_path / "ev").exists()
    # and a model that diverged is never saved
    model, _ = load_checkpoint(SHIPPED_WEIGHTS / "traphic.pt", SHIPPED_WEIGHTS / "traphic.json")
    with torch.no_grad():
        next(model.parameters()).fill_(float("inf"))
    with pytest.raises(UserError, match="refusing to save"):
        save_checkpoint(model, tmp_path / "m.pt")
    assert not list(tmp_path.glob("*m.pt*"))


# ---------------------------------------------------------------------- seeds
def test_seed_lists_are_bounded_before_anything_is_allocated(capsys) -> None:
    assert parse_seeds("0-2,7") == [0, 1, 2, 7] and len(parse_seeds(f"0-{MAX_SEEDS - 1}")) == MAX_SEEDS
    assert parse_seeds(f"{2**31 - 1}") == [2**31 - 1]
    for bad in ("0-99999999999", f"0-{MAX_SEEDS}", f"{2**31}", "-1", "5-3", "1e3", "nan", ""):
        with pytest.raises(Exception) as e:
            parse_seeds(bad)
        assert "bad seed list" in str(e.value)
    with pytest.raises(SystemExit) as e:
        main(["generate", "x", "--out", "y", "--seeds", "0-99999999999"])
    assert e.value.code == 2 and "seeds must be in 0..2147483647" in capsys.readouterr().err


# ---------------------------------------------------------------------- one output-folder rule
def test_non_empty_output_folders_need_force_and_data_sets_are_never_outputs(tmp_path: Path, capsys) -> None:
    data = write_dataset([flow_scene(0), flow_scene(1)], tmp_path / "data", {"source": "test"})
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "mine.txt").write_text("keep me")
    scenario = tmp_path / "tiny.toml"
    scenario.write_text(TINY)
    commands = {
        "evaluate": ["evaluate", "--data", str(data), "--model", "const-vel", "--split", "all"],
        "train": ["train", "--data", str(data), "--model", "traphic-b"],
        "closedloop": ["closedloop", str(scenario), "--predictor", "const-vel"],
        "sweep": ["sweep", str(scenario), "--set", "demand_scale=1"],
        "benchmark": ["benchmark", "--data", str(data)],
    }
    for name, argv in commands.items():
        assert main([*argv, "--out", str(busy)]) == 2, name
        one_error_line(capsys, str(busy), "not empty", "--force")
        assert main([*argv, "--out", str(data), "--force"]) == 2, name
        one_error_line(capsys, str(data), "is a data set folder")
    assert main([*commands["evaluate"], "--out", str(busy), "--force"]) == 0
    assert (busy / "metrics.json").is_file() and (busy / "mine.txt").read_text() == "keep me"
    assert sorted(p.name for p in data.iterdir()) == [MANIFEST, "scene-000000.parquet", "scene-000001.parquet"]


# ---------------------------------------------------------------------- imported real data sets
IMPORTS = [("eth-ucy", "eth_ucy"), ("traf", "traf/TRAF11_gt.txt"), ("apolloscape", "apolloscape"),
           ("commonroad", "commonroad_ngsim"), ("argoverse2", "av2"), ("tracknpred", "tracknpred/TrainSet.txt")]


@pytest.mark.parametrize(("fmt", "src"), IMPORTS, ids=[f for f, _ in IMPORTS])
def test_stats_table_of_every_imported_real_data_set(fmt: str, src: str, tmp_path: Path, capsys) -> None:
    out = tmp_path / "ds"
    assert main(["import", fmt, str(DATA / src), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["stats", str(out)]) == 0
    table = capsys.readouterr().out
    assert "Density/km" in table and fmt in table.splitlines()[1]
    assert len(pd.read_parquet(out)) == read_manifest(out)["rows"]


BAD_SOURCES = [
    ("eth-ucy", "0 1 1.0 2.0\n10 1 1.5 2.0\n1e18 1 2.0 2.0\n", "frame 1e+18 is out of range"),
    ("eth-ucy", "0 1 1.0 2.0\n10 1 1e300 2.0\n", "must be finite and within"),
    ("eth-ucy", "0 1 1.0 2.0\n10 1 1.5 2.0\n100000000 1 2.0 2.0\n", "at most 1,000,000"),
    ("eth-ucy", "0 1 1.0 2.0\n-9223372036854775808 1 2 2\n", "out of range"),
    ("traf", "100000000000000000000,1,1,1,1,1,car1\n", "out of range"),
    ("traf", "0,1,1e300,1,1,1,car1\n", "must be finite and within"),
    ("apolloscape", "1 1 1 0 0\n1e15 1 1 0 0\n", "out of range"),
    ("tracknpred", "1,1,0,1.0,2.0\n1,1,5000000,1.0,2.0\n", "at most 1,000,000"),
    ("commonroad", '<commonRoad timeStepSize="nan"><dynamicObstacle id="1"><type>car</type><initialState>'
                   "<position><point><x>0</x><y>0</y></point></position><orientation><exact>0</exact></orientation>"
                   "<time><exact>0</exact></time><velocity><exact>1</exact></velocity></initialState>"
                   "</dynamicObstacle></commonRoad>", "frame interval"),
]


@pytest.mark.parametrize(("fmt", "text", "needle"), BAD_SOURCES)
def test_hostile_sources_are_one_line_and_exit_2(fmt: str, text: str, needle: str, tmp_path: Path, capsys) -> None:
    src = tmp_path / ("src.xml" if fmt == "commonroad" else "src.txt")
    src.write_text(text)
    assert main(["import", fmt, str(src), "--out", str(tmp_path / "out")]) == 2
    one_error_line(capsys, str(src), needle)
    assert not (tmp_path / "out").exists()


def test_manifest_never_holds_nan(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="NaN or infinity"):
        write_dataset([flow_scene(0)], tmp_path / "ds", {"source": "test", "bad": float("nan")})
    assert not (tmp_path / "ds").exists()
    json.loads((write_dataset([flow_scene(0)], tmp_path / "ok", {"x": 1.0}) / MANIFEST).read_text())


# ---------------------------------------------------------------------- a lying manifest never deletes intact data
def _edit_manifest(folder: Path, index: int, **fields: object) -> None:
    manifest = json.loads((folder / MANIFEST).read_text())
    manifest["scenes"][index].update(fields)
    (folder / MANIFEST).write_text(json.dumps(manifest))


@pytest.mark.parametrize("lie", ["sha256", "bytes"])
def test_a_wrong_manifest_entry_is_repaired_and_the_intact_shard_kept(tiny, tmp_path: Path, capsys, lie: str) -> None:
    scenario, ref = tiny
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    entry = read_manifest(out)["scenes"][1]
    wrong = ("0" if entry["sha256"][0] != "0" else "1") + entry["sha256"][1:] if lie == "sha256" else \
        entry["bytes"] + 7
    _edit_manifest(out, 1, **{lie: wrong})
    with pytest.raises(UserError, match="scene-000001.parquet: .*yet the shard reads intact.*entry is wrong"):
        Dataset(out)
    capsys.readouterr()
    assert main(["generate", str(scenario), "--seeds", "0", "--out", str(out), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert "scene-000001.parquet" in err and "entry is repaired" in err and "removed" not in err
    assert data_files(out) == data_files(ref)  # the shard byte-identical, the manifest as a clean run's


def test_an_intact_shard_under_another_seeds_name_is_damaged(tiny, tmp_path: Path, capsys) -> None:
    scenario, ref = tiny
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    shutil.copy(out / "scene-000000.parquet", out / "scene-000001.parquet")  # self-consistent, wrong name
    assert main(["generate", str(scenario), "--seeds", "0-1", "--out", str(out), "--workers", "1"]) == 0
    assert "scene-000001.parquet: damaged (holds scene 'scene-000000'" in capsys.readouterr().err
    assert data_files(out) == data_files(ref)


# ---------------------------------------------------------------------- nothing is written inside a data set
def test_no_command_writes_inside_a_data_set_folder(tiny, tmp_path: Path, capsys) -> None:
    scenario, _ = tiny
    data = write_dataset([flow_scene(0), flow_scene(1)], tmp_path / "data", {"source": "test"})
    (tmp_path / "link").symlink_to(data)
    before = data_files(data)
    inside = [data / "sub", data / "a" / "b", tmp_path / "link" / "sub"]
    commands = {
        "evaluate": lambda o: ["evaluate", "--data", str(data), "--model", "const-vel", "--split", "all", "--out", o],
        "generate": lambda o: ["generate", str(scenario), "--out", o, "--workers", "1"],
        "export": lambda o: ["export", "tracknpred", str(data), "--out", o],
        "stats": lambda o: ["stats", str(data), "--figure", o + "/x.png"],
        "train": lambda o: ["train", "--data", str(data), "--model", "traphic-b", "--out", o],
        "closedloop": lambda o: ["closedloop", str(scenario), "--predictor", "const-vel", "--out", o],
        "sweep": lambda o: ["sweep", str(scenario), "--set", "demand_scale=1", "--out", o],
        "sensitivity": lambda o: ["sensitivity", str(scenario), "--perturb", "noise=0", "--out", o],
        "benchmark": lambda o: ["benchmark", "--data", str(data), "--out", o],
        "import": lambda o: ["import", "eth-ucy", str(DATA / "eth_ucy"), "--out", o],
    }
    for name, argv in commands.items():
        for out in inside:
            assert main(argv(str(out))) == 2, (name, out)
            one_error_line(capsys, "lies inside the data set folder")
    assert data_files(data) == before and sorted(p.name for p in data.iterdir()) == sorted(before)
    assert len(pd.read_parquet(data)) == read_manifest(data)["rows"]


# ---------------------------------------------------------------------- crafted files: one line, exit 2
def _crafted_shard(path: Path, info: object = None, x_nan: bool = False, raw: bytes | None = None) -> None:
    """Rewrite the shard at `path` with its `simharness` metadata replaced (by `info` as JSON, or `raw`)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    if x_nan:
        x = table.column("x").to_numpy().copy()
        x[0] = float("nan")
        table = table.set_column(table.schema.get_field_index("x"), "x", pa.array(x))
    meta = raw if raw is not None else json.dumps(info).encode() if info is not None else \
        table.schema.metadata[b"simharness"]
    pq.write_table(table.replace_schema_metadata({b"simharness": meta}), path)


def _info(path: Path) -> dict:
    import pyarrow.parquet as pq

    return json.loads(pq.read_schema(path).metadata[b"simharness"])


CRAFTED = {
    "not json": ({"raw": b"{not json"}, "not valid JSON"),
    "a list": ({"info": [1, 2]}, "expected a JSON object"),
    "no agents": ({"drop": "agents"}, "field 'agents'"),
    "1e11 frames": ({"set": ("num_frames", 10**11)}, "field 'num_frames'"),
    "NaN dt": ({"set": ("dt", float("nan"))}, "field 'dt'"),
    "NaN in x": ({"x_nan": True}, "column 'x' holds NaN"),
}


@pytest.mark.parametrize("case", sorted(CRAFTED))
def test_crafted_shard_metadata_is_one_line_and_removed_by_generate(tiny, tmp_path: Path, capsys, case: str) -> None:
    scenario, ref = tiny
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    shard = out / "scene-000001.parquet"
    how, needle = CRAFTED[case]
    info = _info(shard)
    if "drop" in how:
        del info[how["drop"]]
    if "set" in how:
        info[how["set"][0]] = how["set"][1]
    _crafted_shard(shard, info=how.get("info", info), x_nan=how.get("x_nan", False), raw=how.get("raw"))
    _edit_manifest(out, 1, bytes=shard.stat().st_size, sha256=file_sha256(shard))  # listed as it is now
    assert main(["stats", str(out)]) == 2
    one_error_line(capsys, "scene-000001.parquet", needle)
    manifest = read_manifest(out)  # unlisted, as a killed run leaves it: judged by its own bytes alone
    write_manifest(out, build_manifest(manifest["scenes"][:1], manifest["info"]))
    assert main(["generate", str(scenario), "--seeds", "0", "--out", str(out), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert "scene-000001.parquet: damaged" in err and needle in err and "rerun with --seeds 1" in err
    assert not shard.exists() and Dataset(out).scene_ids == ["scene-000000"]


RUN_CONFIGS = {
    "encoder abc": (("model_config", "encoder"), "abc", "model_config.encoder"),
    "encoder 200000": (("model_config", "encoder"), 200000, "model_config.encoder"),
    "model_config a list": (("model_config",), [1, 2], "model_config"),
    "hz 0": (("window", "hz"), 0, "window.hz"),
    "hz NaN": (("window", "hz"), float("nan"), "window.hz"),
    "history_s -3": (("window", "history_s"), -3, "window.history_s"),
    "history_s 1e9": (("window", "history_s"), 1e9, "window.history_s"),
    "model 7": (("model",), 7, "'model'"),
}


@pytest.mark.parametrize("case", sorted(RUN_CONFIGS))
def test_crafted_run_config_is_one_line_naming_the_field(tmp_path: Path, capsys, case: str) -> None:
    keys, value, needle = RUN_CONFIGS[case]
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(SHIPPED_WEIGHTS / "traphic.pt", run / "model.pt")
    cfg = json.loads((SHIPPED_WEIGHTS / "traphic.json").read_text())
    node = cfg
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = value
    (run / "config.json").write_text(json.dumps(cfg))
    data = write_dataset([flow_scene(0)], tmp_path / "data", {"source": "test"})
    assert main(["evaluate", "--data", str(data), "--model", str(run), "--split", "all"]) == 2
    one_error_line(capsys, "config.json", needle)


def test_crafted_scenario_and_npy_are_one_line(tmp_path: Path, capsys) -> None:
    import numpy as np

    deep = tmp_path / "deep.toml"
    deep.write_text("x = " + "[" * 100_000 + "]" * 100_000 + "\n")
    assert main(["scenario", str(deep)]) == 2
    one_error_line(capsys, "deep.toml", "nested too deeply")
    npy = tmp_path / "huge.npy"
    with open(npy, "wb") as f:  # a header declaring 34 TiB over 80 bytes of data
        np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (2**40, 5)})
        f.write(bytes(80))
    assert main(["import", "tracknpred", str(npy), "--out", str(tmp_path / "out")]) == 2
    one_error_line(capsys, "huge.npy", "header declares an array of shape")
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------- filesystem errors
def _read_only_folder(tmp_path: Path) -> Path:
    """A folder this process cannot write to: mode 0555, or for root (whom modes do not stop) /proc/sys."""
    import os

    if os.geteuid() == 0:
        return Path("/proc/sys")
    folder = tmp_path / "ro"
    folder.mkdir(mode=0o555)
    return folder


def test_unwritable_outputs_are_one_line_and_exit_2(tiny, tmp_path: Path, capsys) -> None:
    scenario, data = tiny
    (tmp_path / "afile").write_text("x")
    for out in (_read_only_folder(tmp_path) / "out", tmp_path / "afile" / "sub"):
        for argv in (["generate", str(scenario), "--workers", "1"],
                     ["evaluate", "--data", str(data), "--model", "const-vel", "--split", "all"],
                     ["import", "eth-ucy", str(DATA / "eth_ucy")],
                     ["closedloop", str(scenario), "--predictor", "const-vel"]):
            assert main([*argv, "--out", str(out)]) == 2, argv
            one_error_line(capsys, "not writable" if "afile" not in str(out) else "which is a file")
    (tmp_path / "folder.png").mkdir()
    for figure, needle in ((tmp_path / "folder.png", "names a folder"), (tmp_path / "afile" / "x.png", "a file"),
                           (tmp_path / "x.xyz", "suffix '.xyz'")):
        assert main(["stats", str(data), "--figure", str(figure)]) == 2
        one_error_line(capsys, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "folder.png"] + (
        ["ro"] if (tmp_path / "ro").exists() else [])


def test_os_errors_on_a_path_are_one_line(capsys) -> None:
    import errno

    from simharness.cli import run_guarded

    def job() -> int:
        raise OSError(errno.EROFS, "Read-only file system", "/data/out")

    assert run_guarded(job) == 2
    one_error_line(capsys, "/data/out: Read-only file system")


# ---------------------------------------------------------------------- bad numbers
def test_bad_seeds_and_empty_demand_are_one_line(tiny, tmp_path: Path, capsys) -> None:
    scenario, data = tiny
    for seed in ("-1", "99999999999999999999", "2147483648"):
        with pytest.raises(SystemExit) as e:
            main(["train", "--data", str(data), "--out", str(tmp_path / "t"), "--seed", seed])
        assert e.value.code == 2 and "expected a seed in 0..2147483647" in capsys.readouterr().err
    big = tmp_path / "big.toml"
    big.write_text(TINY.replace('name = "tiny"', 'name = "big"\nseed = 2147483647'))
    for argv in (["generate", str(big), "--workers", "1"], ["closedloop", str(big), "--predictor", "const-vel"]):
        assert main([*argv, "--seeds", "2147483647", "--out", str(tmp_path / "o")]) == 2
        one_error_line(capsys, "big.toml", "4294967294", "seed range 0..2147483647")
    assert main(["generate", str(big), "--seeds", "0", "--out", str(tmp_path / "o"), "--workers", "1",
                 "--duration", "0.4"]) == 0  # the sum in range: runs
    zero = tmp_path / "zero.toml"
    zero.write_text(TINY.replace("car = 1800", "car = 0").replace("motorcycle = 900", "motorcycle = 0.0"))
    scaled = tmp_path / "scaled.toml"
    scaled.write_text(TINY.replace('backend = "sumo"', 'backend = "sumo"\ndemand_scale = 0'))
    for bad in (zero, scaled):
        assert main(["generate", str(bad), "--out", str(tmp_path / "z")]) == 2
        one_error_line(capsys, bad.name, "key 'demand': no agents at all")
    assert not (tmp_path / "t").exists() and not (tmp_path / "z").exists()


# ---------------------------------------------------------------------- symbolic links, leftovers, modes
@pytest.mark.parametrize("name", ["_runs.jsonl", "_lock", "_manifest.json"])
def test_a_symlink_in_the_data_set_folder_is_never_followed(tiny, tmp_path: Path, capsys, name: str) -> None:
    scenario, ref = tiny
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    target = tmp_path / "outside.txt"
    target.write_text("keep")
    if name == "_manifest.json":
        shutil.move(out / name, target)
    else:
        (out / name).unlink()
    (out / name).symlink_to(target)
    before = target.read_bytes()
    assert main(["generate", str(scenario), "--seeds", "0", "--out", str(out), "--workers", "1"]) == 2
    one_error_line(capsys, name, "symbolic link")
    assert target.read_bytes() == before


def test_leftovers_of_killed_runs_go_and_refusals_leave_nothing(tiny, tmp_path: Path, capsys) -> None:
    import os
    import stat

    scenario, _ = tiny
    out = tmp_path / "imp"
    dead = tmp_path / ".tmp-imp.999999999.abcd"  # what a kill -9 during `import` leaves (no such pid)
    dead.mkdir()
    (dead / "scene.parquet").write_bytes(bytes(1000))
    live = tmp_path / f".tmp-imp.{os.getpid()}.efgh"  # a writer still running: left alone
    live.mkdir()
    assert main(["import", "eth-ucy", str(DATA / "eth_ucy"), "--out", str(out)]) == 0
    assert not dead.exists() and live.exists()
    old = os.umask(0o022)
    try:
        shutil.rmtree(out)
        assert main(["import", "eth-ucy", str(DATA / "eth_ucy"), "--out", str(out)]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
    assert {stat.S_IMODE(p.stat().st_mode) for p in out.iterdir()} == {0o644}
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "mine.txt").write_text("x")
    capsys.readouterr()
    assert main(["generate", str(scenario), "--out", str(busy), "--workers", "1"]) == 2
    one_error_line(capsys, "mine.txt")
    assert sorted(p.name for p in busy.iterdir()) == ["mine.txt"]  # no _lock
    # a killed evaluate/train left half-written files inside its --out: the next run into it removes them
    (busy / ".tmp-metrics.json.999999999.x1y2").write_text("{")
    (busy / f".tmp-model.pt.{os.getpid()}.w").write_text("live")
    prepare_output(busy, force=True)
    assert sorted(p.name for p in busy.iterdir()) == [f".tmp-model.pt.{os.getpid()}.w", "mine.txt"]
