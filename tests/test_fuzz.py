"""Property-based fuzzing (hypothesis) of the scenario loader and every importer, through the CLI in-process.

The property: any input gives either a valid result (exit 0, and for an import a data set that opens) or
one line `simharness: error: ...` and exit 2; never a traceback, never a half-written output. Inputs are
near-valid (the format's layout with hostile values: NaN, infinities, 1e300, huge or negative frame
numbers, words, empty fields) so that they reach deep into each parser. Budget: a few seconds per target.
"""

from __future__ import annotations

import contextlib
import io
import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simharness.cli import main
from simharness.io.parquet import Dataset

FUZZ = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# numbers as a hostile user writes them: ordinary, huge, tiny, negative, non-finite, and not numbers at all
NUMBER_TEXT = st.one_of(
    st.integers(-5, 60).map(str),
    st.floats(-1e4, 1e4, allow_nan=False).map(lambda v: f"{v:.3f}"),
    st.sampled_from(["nan", "inf", "-inf", "1e18", "-1e18", "1e300", "9223372036854775808", "1e-300", "0", "-0",
                     "", "abc", "1,5", "0x10", "NaN", "+7", "1e999", " ", "\u00e9"]),
)


def run_cli(argv: list[str]) -> tuple[int, str]:
    """(exit code, stderr without progress bars) of `simharness ARGV` run in this process."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        code = main(argv)
    # a progress bar left open by the error shares its line with the message: split them
    text = err.getvalue().replace("\r", "\n").replace("simharness: ", "\nsimharness: ")
    lines = [line for line in text.splitlines()
             if line.strip() and "%|" not in line]  # tqdm bars: "import traf:  0%|   | 0/1 [...]"
    return code, "\n".join(lines)


def check_outcome(code: int, err: str, out: Path | None) -> None:
    assert "Traceback" not in err
    if code == 0:
        if out is not None:
            assert len(Dataset(out)) >= 1
        return
    assert code == 2, (code, err)
    assert len(err.splitlines()) == 1 and err.startswith("simharness: error: "), err
    if out is not None:
        assert not out.exists(), "a refused import left files"


# ---------------------------------------------------------------------- scenario loader
SCALAR = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**70, 2**70), st.booleans(),
                   st.text(max_size=8), st.lists(st.integers(0, 3), max_size=2))
KEYS = ["name", "backend", "seed", "duration", "warmup", "step_length", "record_hz", "demand_scale", "bogus"]
TABLES = {"road": ["layout", "length", "width", "lanes", "bidirectional", "sidewalk_width", "speed_limit"],
          "demand": ["car", "bus", "truck", "rickshaw", "motorcycle", "pedestrian", "plane"],
          "pedestrians": ["crossing_rate", "walking_rate", "speed"], "behaviour": ["spread", "speed_dev"],
          "sublane": ["lateral_resolution", "min_gap_lat", "lane_discipline"],
          "ego": ["enabled", "type", "insert_at", "speed", "reaction"]}


def toml_value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').encode("ascii", "backslashreplace").decode() + '"'
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return str(v)


@st.composite
def scenario_text(draw: st.DrawFn) -> str:
    lines = ['name = "fuzz"', 'backend = "sumo"'] if draw(st.booleans()) else []
    for key in draw(st.lists(st.sampled_from(KEYS[2:]), max_size=4, unique=True)):
        lines.append(f"{key} = {toml_value(draw(SCALAR))}")
    for table in draw(st.lists(st.sampled_from(sorted(TABLES)), max_size=4, unique=True)):
        lines.append(f"[{table}]")
        for key in draw(st.lists(st.sampled_from(TABLES[table]), min_size=1, max_size=3, unique=True)):
            value = draw(st.one_of(SCALAR, st.floats(0, 3000)))
            lines.append(f"{key} = {toml_value(value)}")
    return "\n".join(lines) + "\n"


@FUZZ
@given(text=st.one_of(scenario_text(), st.text(max_size=200)))
def test_scenario_loader_never_tracebacks(text: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzz.toml"
        path.write_text(text, encoding="utf-8", errors="replace")
        code, err = run_cli(["scenario", str(path)])
        check_outcome(code, err, None)


# ---------------------------------------------------------------------- importers (text formats)
def rows_of(fields: int, sep: str) -> st.SearchStrategy[str]:
    row = st.lists(NUMBER_TEXT, min_size=fields - 1, max_size=fields + 1).map(sep.join)
    return st.lists(row, min_size=1, max_size=8).map(lambda rs: "\n".join(rs) + "\n")


@st.composite
def traf_text(draw: st.DrawFn) -> str:
    lines = []
    for _ in range(draw(st.integers(1, 5))):
        n = draw(st.integers(0, 3))
        groups = [",".join([*(draw(NUMBER_TEXT) for _ in range(4)), draw(st.sampled_from(
            ["car1", "bus2", "ped3", "null", "rickshaw4", "7", "", "x,y"]))]) for _ in range(n)]
        count = draw(st.one_of(st.just(str(n)), NUMBER_TEXT))
        lines.append(",".join([draw(NUMBER_TEXT), count, *groups]))
    return "\n".join(lines) + "\n"


TEXT_SOURCES = {
    "eth-ucy": rows_of(4, "\t"),
    "apolloscape": st.one_of(rows_of(5, " "), rows_of(10, " ")),
    "tracknpred": st.one_of(rows_of(5, ","), rows_of(5, "\t")),
    "traf": traf_text(),
}


def import_and_check(fmt: str, write: object) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        src = write(Path(tmp))
        out = Path(tmp) / "out"
        code, err = run_cli(["import", fmt, str(src), "--out", str(out)])
        check_outcome(code, err, out)


@FUZZ
@given(data=st.data())
def test_text_importers_never_traceback(data: st.DataObject) -> None:
    fmt = data.draw(st.sampled_from(sorted(TEXT_SOURCES)))
    text = data.draw(TEXT_SOURCES[fmt])

    def write(folder: Path) -> Path:
        path = folder / "src.txt"
        path.write_text(text, encoding="utf-8")
        return path

    import_and_check(fmt, write)


# ---------------------------------------------------------------------- CommonRoad XML
@st.composite
def commonroad_xml(draw: st.DrawFn) -> str:
    def v() -> str:
        return draw(NUMBER_TEXT).replace("<", "").replace("&", "")

    states = []
    for k in range(draw(st.integers(0, 3))):
        time = k + 1 if draw(st.booleans()) else v()
        states.append(f"<state><position><point><x>{v()}</x><y>{v()}</y></point></position>"
                      f"<orientation><exact>{v()}</exact></orientation><time><exact>{time}"
                      f"</exact></time><velocity><exact>{v()}</exact></velocity></state>")
    shape = draw(st.sampled_from([f"<rectangle><length>{v()}</length><width>{v()}</width></rectangle>",
                                  f"<circle><radius>{v()}</radius></circle>", ""]))
    init = (f"<initialState><position><point><x>{v()}</x><y>{v()}</y></point></position><orientation><exact>"
            f"{v()}</exact></orientation><time><exact>0</exact></time><velocity><exact>{v()}</exact></velocity>"
            "</initialState>") if draw(st.integers(0, 5)) else ""
    obstacle = (f'<dynamicObstacle id="{draw(st.integers(1, 9))}"><type>{draw(st.sampled_from(["car", "bus", "ufo"]))}'
                f"</type><shape>{shape}</shape>{init}<trajectory>{''.join(states)}</trajectory></dynamicObstacle>")
    lanelet = (f'<lanelet id="1"><leftBound><point><x>{v()}</x><y>{v()}</y></point><point><x>1</x><y>1</y></point>'
               "</leftBound><rightBound><point><x>0</x><y>0</y></point><point><x>1</x><y>0</y></point></rightBound>"
               "</lanelet>") if draw(st.booleans()) else ""
    root = draw(st.sampled_from(["commonRoad", "commonRoad", "other"]))
    return f'<{root} timeStepSize="{v()}">{lanelet}{obstacle * draw(st.integers(0, 2))}</{root}>'


@FUZZ
@given(xml=st.one_of(commonroad_xml(), st.text(max_size=80)))
def test_commonroad_importer_never_tracebacks(xml: str) -> None:
    def write(folder: Path) -> Path:
        path = folder / "src.xml"
        path.write_text(xml, encoding="utf-8", errors="replace")
        return path

    import_and_check("commonroad", write)


# ---------------------------------------------------------------------- Argoverse 2 Parquet, TrackNPred .npy
NUMBERS = st.one_of(st.floats(-1e4, 1e4), st.sampled_from([math.nan, math.inf, -math.inf, 1e18, 1e300, 0.5, -3.0]))


@FUZZ
@given(rows=st.integers(0, 6), data=st.data())
def test_argoverse2_importer_never_tracebacks(rows: int, data: st.DataObject) -> None:
    cols = {"track_id": data.draw(st.lists(st.sampled_from(["AV", "1", "2", ""]), min_size=rows, max_size=rows)),
            "object_type": data.draw(st.lists(st.sampled_from(["vehicle", "pedestrian", "ufo"]), min_size=rows,
                                              max_size=rows)),
            "object_category": data.draw(st.lists(st.integers(0, 3), min_size=rows, max_size=rows)),
            "timestep": data.draw(st.lists(st.one_of(st.integers(0, 110).map(float), NUMBERS), min_size=rows,
                                           max_size=rows))}
    for c in ("position_x", "position_y", "heading", "velocity_x", "velocity_y"):
        cols[c] = data.draw(st.lists(NUMBERS, min_size=rows, max_size=rows))
    cols["observed"] = data.draw(st.lists(st.booleans(), min_size=rows, max_size=rows))
    drop = data.draw(st.sampled_from([None, "heading", "observed"]))
    df = pd.DataFrame({k: v for k, v in cols.items() if k != drop})

    def write(folder: Path) -> Path:
        path = folder / "src.parquet"
        df.to_parquet(path)
        return path

    import_and_check("argoverse2", write)


@FUZZ
@given(rows=st.integers(0, 6), width=st.integers(1, 7), data=st.data())
def test_tracknpred_npy_importer_never_tracebacks(rows: int, width: int, data: st.DataObject) -> None:
    arr = np.array(data.draw(st.lists(NUMBERS, min_size=rows * width, max_size=rows * width)), np.float64)
    arr = arr.reshape(rows, width)

    def write(folder: Path) -> Path:
        path = folder / "src.npy"
        np.save(path, arr)
        return path

    import_and_check("tracknpred", write)


# ---------------------------------------------------------------------- run configs, shard metadata, manifests
# JSON values as a hostile user writes them into a file the project reads back
JSON_VALUE = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(), st.text(max_size=6),
                       st.lists(st.integers(-3, 10**12), max_size=3), st.dictionaries(st.text(max_size=3),
                                                                                     st.integers(), max_size=2),
                       st.sampled_from([0, -1, 1e9, 1e11, 2**31, "abc", [], {}, [1, 2]]))


def paths_of(obj: object, prefix: tuple = (), depth: int = 3) -> list[tuple]:
    """Every key path into nested dicts and lists, down to `depth`."""
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else []
    out = []
    for k, v in items:
        out.append((*prefix, k))
        if depth > 1:
            out += paths_of(v, (*prefix, k), depth - 1)
    return out


def mutate(obj: object, data: st.DataObject, times: int = 2) -> object:
    """`obj` (a JSON document) with up to `times` values replaced by hostile ones or deleted."""
    import copy

    obj = copy.deepcopy(obj)
    for _ in range(data.draw(st.integers(1, times))):
        paths = paths_of(obj)
        if not paths:
            return data.draw(JSON_VALUE)
        *parent, key = data.draw(st.sampled_from(paths))
        node = obj
        for k in parent:
            node = node[k]
        if data.draw(st.booleans()) and isinstance(node, dict):
            del node[key]
        else:
            node[key] = data.draw(JSON_VALUE)
    return obj


SHIPPED = Path(__file__).resolve().parent.parent / "predictor" / "weights"


@FUZZ
@given(data=st.data())
def test_run_config_reader_never_tracebacks(data: st.DataObject) -> None:
    import json

    from predictor.checkpoint import read_config
    from predictor.features import WindowConfig
    from predictor.models import config_class
    from simharness.errors import UserError

    name = data.draw(st.sampled_from(["traphic", "cs-lstm", "social-gan"]))
    cfg = mutate(json.loads((SHIPPED / f"{name}.json").read_text()), data)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "config.json"
        path.write_text(json.dumps(cfg))
        try:
            good = read_config(path)
        except UserError as e:
            assert str(e).startswith(str(path)) and "\n" not in str(e)
            return
    # accepted: the window and model config build (bounded sizes) without any other error
    window = WindowConfig.from_dict(good["window"])
    with contextlib.suppress(UserError):
        window.frames(0.1)
    config_class(good["model"])(**{k: tuple(v) if isinstance(v, list) else v for k, v in good["model_config"].items()})


def _write_with_info(folder: Path, info: object, x_nan: bool = False) -> Path:
    """A shard whose `simharness` metadata is `info` (JSON-encoded as is), rows of a real scene."""
    import json

    import pyarrow.parquet as pq
    from conftest import make_scene

    from simharness.io.parquet import META_KEY, scene_table

    table = scene_table(make_scene(), "scene-000000")
    if x_nan:
        x = table.column("x").to_numpy().copy()
        x[1] = np.nan
        table = table.set_column(table.schema.get_field_index("x"), "x", pa.array(x))
    table = table.replace_schema_metadata({META_KEY: json.dumps(info).encode()})
    path = folder / "scene-000000.parquet"
    pq.write_table(table, path)
    return path


def _shard_info_of_a_real_scene() -> dict:
    import json

    from conftest import make_scene

    from simharness.io.parquet import META_KEY, scene_table

    return json.loads(scene_table(make_scene(), "scene-000000").schema.metadata[META_KEY])


@FUZZ
@given(data=st.data())
def test_shard_metadata_reader_never_tracebacks(data: st.DataObject) -> None:
    from simharness.errors import UserError
    from simharness.io.parquet import describe_shard, read_scene, shard_damage

    info = mutate(_shard_info_of_a_real_scene(), data)
    with tempfile.TemporaryDirectory() as tmp:
        path = _write_with_info(Path(tmp), info, x_nan=data.draw(st.booleans()))
        for read in (read_scene, describe_shard):
            with contextlib.suppress(UserError):
                read(path)
        damage = shard_damage(path)
        assert damage is None or "\n" not in damage


@FUZZ
@given(data=st.data())
def test_manifest_reader_never_tracebacks(data: st.DataObject) -> None:
    import json

    from conftest import make_scene

    from simharness.io.parquet import MANIFEST, write_dataset

    with tempfile.TemporaryDirectory() as tmp:
        folder = write_dataset([make_scene(seed=0), make_scene(seed=1)], Path(tmp) / "ds", {"source": "fuzz"})
        manifest = json.loads((folder / MANIFEST).read_text())
        manifest["info"]["road"] = {"drivable": [[[0.0, -5.0], [100.0, -5.0], [100.0, 5.0]]], "markings": []}
        manifest = mutate(manifest, data, times=3)
        (folder / MANIFEST).write_text(json.dumps(manifest))
        code, err = run_cli(["stats", str(folder), "--json"])
        check_outcome(code, err, None)
