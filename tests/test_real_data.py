"""Real data end to end: leave-one-scene-out splits, TraPHic trained and scored on ETH/UCY and TRAF samples."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from predictor.split import split_scenes
from simharness.cli import main
from simharness.errors import UserError
from simharness.io import importers as im
from simharness.io.parquet import Dataset
from simharness.scene import AgentType

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="module")
def datasets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("real")
    # TRAF11 and TRAF12: the two videos the figures below were measured on (the folder holds 17).
    traf = [str(DATA / "traf" / f"TRAF{k}_gt.txt") for k in (11, 12)]
    for fmt, src in (("eth-ucy", [str(DATA / "eth_ucy")]), ("traf", traf)):
        assert main(["import", fmt, *src, "--out", str(root / fmt.replace("-", "_"))]) == 0
    return {"eth": root / "eth_ucy", "traf": root / "traf", "root": root}


def test_split_holds_out_named_scenes():
    two = ["biwi_hotel", "crowds_zara01"]
    assert split_scenes(two, test_scenes=["hotel"]) == {
        "test": ["biwi_hotel"], "train": ["crowds_zara01"], "val": ["crowds_zara01"]}
    assert split_scenes(two, test_scenes=["crowds_zara01"])["train"] == ["biwi_hotel"]  # an exact id
    five = ["biwi_eth", "biwi_hotel", "crowds_zara01", "crowds_zara02", "students003"]
    s = split_scenes(five, test_scenes=["ETH"])  # case-insensitive
    assert s["test"] == ["biwi_eth"] and len(s["val"]) == 1 and len(s["train"]) == 3
    assert not set(s["val"]) & set(s["train"]) and sorted(s["val"] + s["train"] + s["test"]) == five
    with pytest.raises(UserError, match="'zara' matches 2 scenes"):
        split_scenes(five, test_scenes=["zara"])
    with pytest.raises(UserError, match="'univ' matches no scene; the data set's scenes are biwi_eth"):
        split_scenes(five, test_scenes=["univ"])
    with pytest.raises(UserError, match="leave no scene to train on"):
        split_scenes(two, test_scenes=["hotel", "zara"])
    with pytest.raises(UserError, match="--test-scenes"):
        split_scenes(two)


def test_traf_records_pixel_scale():
    t11, t12 = im.import_traf([DATA / "traf" / "TRAF11_gt.txt", DATA / "traf" / "TRAF12_gt.txt"])
    for scene, expected in ((t11, 63.53), (t12, 75.88)):
        cars = scene.agent_type == AgentType.CAR
        # Hand check: the median car's box is 108 px (TRAF11) / 129 px (TRAF12) wide, over 1.7 m.
        assert scene.meta["units_per_m"] == pytest.approx(np.median(scene.length[cars]) / 1.7, abs=0.01)
        assert scene.meta["units_per_m"] == pytest.approx(expected, abs=0.01)
        assert scene.units == "px" and "not a homography" in scene.meta["units_per_m_note"]


def _metrics(path: Path) -> dict:
    return json.loads((path / "metrics.json").read_text())


def test_leave_one_scene_out_eth_ucy(datasets, capsys):
    """Train TraPHic on zara01 with the eth-ucy windows, score it and constant velocity on the held-out hotel."""
    run, root = datasets["root"] / "run-eth", datasets["root"]
    assert main(["train", "--data", str(datasets["eth"]), "--model", "traphic", "--protocol", "eth-ucy",
                 "--test-scenes", "hotel", "--epochs", "1", "--warmup-epochs", "1", "--max-samples", "256",
                 "--out", str(run)]) == 0
    assert "validation (checkpoint choice) used the training scene(s) crowds_zara01" in capsys.readouterr().out
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["split"] == {"test": ["biwi_hotel"], "train": ["crowds_zara01"], "val": ["crowds_zara01"]}
    assert (cfg["frames"]["history"], cfg["frames"]["future"], cfg["window"]["hz"]) == (8, 12, 2.5)
    for model, out in ((str(run), root / "ev-traphic"), ("const-vel", root / "ev-cv")):
        assert main(["evaluate", "--data", str(datasets["eth"]), "--model", model, "--protocol", "eth-ucy",
                     "--test-scenes", "hotel", "--out", str(out)]) == 0
    traphic, cv = _metrics(root / "ev-traphic"), _metrics(root / "ev-cv")
    assert traphic["scene_ids"] == cv["scene_ids"] == ["biwi_hotel"] and traphic["units"] == "m"
    assert traphic["samples"] == cv["samples"] == 1053  # the same Social-GAN windows for both
    assert cv["ade"] == pytest.approx(0.32, abs=0.02) and cv["fde"] == pytest.approx(0.61, abs=0.02)
    assert math.isfinite(traphic["ade"]) and traphic["nll"] is not None
    # Held-out scenes belong to --split test only.
    assert main(["evaluate", "--data", str(datasets["eth"]), "--model", "const-vel", "--protocol", "eth-ucy",
                 "--split", "all", "--test-scenes", "hotel", "--out", str(root / "ev-bad")]) == 2


def test_traphic_on_traf_pixels(datasets):
    """TraPHic trains on one TRAF video (ellipses sized by its pixel scale) and is scored in pixels on the other."""
    run, root = datasets["root"] / "run-traf", datasets["root"]
    assert main(["train", "--data", str(datasets["traf"]), "--model", "traphic", "--test-scenes", "TRAF12",
                 "--epochs", "1", "--warmup-epochs", "1", "--max-samples", "256", "--out", str(run)]) == 0
    assert main(["evaluate", "--data", str(datasets["traf"]), "--model", str(run), "--protocol", "traphic",
                 "--test-scenes", "TRAF12", "--out", str(root / "ev-traf")]) == 0
    m = _metrics(root / "ev-traf")
    assert m["scene_ids"] == ["TRAF12_gt"] and m["units"] == "px"
    assert (m["protocol"]["history"], m["protocol"]["future"], m["protocol"]["hz"]) == (15, 25, 5.0)
    assert m["samples"] == 218 and len(m["rmse_per_second"]) == 5
    # Agents sit 400-800 px from the image origin: a forecast left in the model's metre-like units would be
    # off by hundreds of px; a barely trained one is off by about 100 px (constant velocity: 47).
    assert 1.0 < m["ade"] < 200.0 and m["fde"] > m["ade"]


# ---------------------------------------------------------------------- every TRAF video usable
def test_import_traf_options_make_bare_numbered_videos_usable(tmp_path, capsys):
    """TRAF13 has bare numeric ids (no class column) and is a 1920x1080 video: the import warns in one line,
    types them with --type-default, estimates a pixel scale from the boxes, and takes the image size from the data."""
    src = DATA / "traf" / "TRAF13_gt.txt"
    assert main(["import", "traf", str(src), "--out", str(tmp_path / "plain")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert err == ["simharness: warning: TRAF13_gt.txt: 42 of 42 ids carry no class (bare numbers): typed other; "
                   "give --type-default TYPE; no cars to estimate a pixel scale from; give --pixel-scale M_PER_PX "
                   "(or --type-default car) to train or evaluate on it"]
    plain = Dataset(tmp_path / "plain").scene("TRAF13_gt")
    assert (plain.agent_type == AgentType.OTHER).all() and "units_per_m" not in plain.meta
    assert plain.meta["image_size"] == [1920, 1080] and plain.dt == pytest.approx(0.05)
    # Training on it stops with a line whose fix is a real option of `import traf`.
    code = main(["train", "--data", str(tmp_path / "plain"), "--test-scenes", "TRAF13", "--out", str(tmp_path / "r")])
    assert code == 2 and "--pixel-scale M_PER_PX" in capsys.readouterr().err

    assert main(["import", "traf", str(src), "--out", str(tmp_path / "typed"), "--type-default", "car",
                 "--fps", "10", "--image-size", "2000x1100"]) == 0
    typed = Dataset(tmp_path / "typed").scene("TRAF13_gt")
    assert (typed.agent_type == AgentType.CAR).all() and typed.dt == pytest.approx(0.1)
    assert typed.meta["units_per_m"] == pytest.approx(np.median(typed.length) / 1.7, abs=0.01)
    assert typed.meta["image_size"] == [2000, 1100] and typed.meta["untyped_ids"] == 42

    # A video with labelled classes but no cars (TRAF15: humans, chairs, desks) takes --pixel-scale.
    assert main(["import", "traf", str(DATA / "traf" / "TRAF15_gt.txt"), "--out", str(tmp_path / "p"),
                 "--pixel-scale", "0.02"]) == 0
    t15 = Dataset(tmp_path / "p").scene("TRAF15_gt")
    assert t15.meta["units_per_m"] == pytest.approx(50.0) and (t15.agent_type == AgentType.PEDESTRIAN).any()
    assert "TRAF15" not in capsys.readouterr().err  # labelled, scaled: nothing to warn about
    # Bad options: one line, nothing written.
    for bad, msg in ((["--image-size", "12x"], "expected WIDTHxHEIGHT"),
                     (["--type-default", "tram"], "unknown agent type"),
                     (["--pixel-scale", "-1"], "positive metres per pixel"), (["--fps", "0"], "positive frame rate")):
        assert main(["import", "traf", str(src), "--out", str(tmp_path / "bad"), *bad]) == 2
        assert msg in capsys.readouterr().err and not (tmp_path / "bad").exists()
    assert main(["import", "eth-ucy", str(DATA / "eth_ucy"), "--out", str(tmp_path / "bad"), "--fps", "5"]) == 2
    assert "option of `import traf`" in capsys.readouterr().err


def test_traf_image_size_from_the_data():
    """The frame size is the smallest common video size holding the boxes (TRAF11 runs 7 px off its 1280 edge)."""
    sizes = {name: im.import_traf([DATA / "traf" / f"{name}_gt.txt"])[0].meta["image_size"]
             for name in ("TRAF11", "TRAF18", "TRAF25", "TRAF37")}
    assert sizes == {"TRAF11": [1280, 720], "TRAF18": [640, 360], "TRAF25": [640, 480], "TRAF37": [960, 540]}


# ---------------------------------------------------------------------- ApolloScape scored from the CLI
@pytest.fixture(scope="module")
def apollo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("apollo") / "apollo"
    assert main(["import", "apolloscape", str(DATA / "apolloscape"), "--out", str(out)]) == 0
    return out


def test_apolloscape_protocol_windows(apollo):
    """2 Hz, 3 observed + 3 predicted frames: a 6-frame chunk gives one window, of the agents in all 6 frames."""
    from simharness.protocols import get_protocol, windows

    p = get_protocol("apolloscape")
    ds = Dataset(apollo)
    scene = ds.scene(ds.scene_ids[0])
    assert scene.dt == 0.5 and p.step(scene.dt) == 1 and (p.history, p.future) == (3, 3)
    wins = list(windows(scene, p))
    assert [now for now, _ in wins] == list(range(2, scene.num_frames - 3))
    now, rows = wins[0]
    assert scene.valid[rows, now - 2:now + 4].all() and not scene.valid[~np.isin(np.arange(scene.num_agents), rows),
                                                                        now - 2:now + 4].all(1).any()


def test_apolloscape_train_evaluate_benchmark(apollo, tmp_path):
    """train / evaluate / benchmark --protocol apolloscape: 3 + 3 frames at 2 Hz end to end on the real sample."""
    from simharness.benchmark import benchmark

    run = tmp_path / "run"
    assert main(["train", "--data", str(apollo), "--protocol", "apolloscape", "--epochs", "1", "--warmup-epochs", "1",
                 "--out", str(run)]) == 0
    cfg = json.loads((run / "config.json").read_text())
    assert (cfg["frames"]["history"], cfg["frames"]["future"], cfg["window"]["hz"]) == (3, 3, 2.0)
    for model in (str(run), "const-vel"):
        assert main(["evaluate", "--data", str(apollo), "--model", model, "--protocol", "apolloscape",
                     "--out", str(tmp_path / "eval" / Path(model).name)]) == 0
    t, cv = _metrics(tmp_path / "eval" / "run"), _metrics(tmp_path / "eval" / "const-vel")
    assert t["samples"] == cv["samples"] > 20 and t["units"] == "m" and len(t["rmse_per_second"]) == 1
    assert t["protocol"]["name"] == "apolloscape" and math.isfinite(t["ade"]) and t["fde"] > 0
    res = benchmark(apollo, "quick", tmp_path / "bench", workers=1, methods=("traphic",), progress=False,
                    protocol="apolloscape")
    assert res["protocol"] == "apolloscape" and res["methods"]["traphic"]["metrics"]["samples"] == cv["samples"]
    assert "1.5 s history, 1.5 s future, 2 Hz" in (tmp_path / "bench" / "results.md").read_text()
    assert main(["benchmark", "--data", str(apollo), "--protocol", "nope", "--out", str(tmp_path / "b2")]) == 2


# ---------------------------------------------------------------------- ETH/UCY validation on *_val files
def _sgan_layout(root: Path) -> Path:
    """A Social-GAN style leave-one-out folder from the real samples: zara01 held out (test/), hotel cut in time
    into its _train (first 80% of lines) and _val files, as the benchmark's own files are."""
    lines = (DATA / "eth_ucy" / "biwi_hotel.txt").read_text().splitlines(keepends=True)
    cut = int(len(lines) * 0.8)
    for sub, name, text in (("train", "biwi_hotel_train.txt", lines[:cut]), ("val", "biwi_hotel_val.txt", lines[cut:]),
                            ("test", "crowds_zara01.txt", (DATA / "eth_ucy" / "crowds_zara01.txt").read_text())):
        (root / sub).mkdir(parents=True, exist_ok=True)
        (root / sub / name).write_text("".join(text))
    return root


def test_split_uses_the_data_sets_own_val_files():
    ids = ["biwi_eth", "biwi_hotel_train", "biwi_hotel_val", "crowds_zara01_train", "crowds_zara01_val"]
    assert split_scenes(ids) == {"test": ["biwi_eth"], "train": ["biwi_hotel_train", "crowds_zara01_train"],
                                 "val": ["biwi_hotel_val", "crowds_zara01_val"]}
    # Every file of all five scenes: holding out hotel drops its _train / _val parts too.
    five = ["biwi_eth", "biwi_hotel", "crowds_zara01", "crowds_zara02", "students003"]
    every = five + [f"{s}_{k}" for s in five for k in ("train", "val")]
    s = split_scenes(every, test_scenes=["hotel"])
    assert s["test"] == ["biwi_hotel"] and s["val"] == [f"{x}_val" for x in five if x != "biwi_hotel"]
    assert s["train"] == [f"{x}_train" for x in five if x != "biwi_hotel"]
    with pytest.raises(UserError, match="leaves no val scene"):
        split_scenes(["biwi_eth", "biwi_eth_val", "biwi_hotel_train"], test_scenes=["eth"])


def test_eth_ucy_training_validates_on_val_files(tmp_path, capsys):
    src = _sgan_layout(tmp_path / "zara1")
    data = tmp_path / "data"
    assert main(["import", "eth-ucy", str(src / "train"), str(src / "val"), str(src / "test"), "--out", str(data)]) == 0
    run = tmp_path / "run"
    assert main(["train", "--data", str(data), "--protocol", "eth-ucy", "--epochs", "1", "--warmup-epochs", "1",
                 "--max-samples", "128", "--out", str(run)]) == 0
    assert "validation (checkpoint choice) used the training" not in capsys.readouterr().out
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["split"] == {"test": ["crowds_zara01"], "train": ["biwi_hotel_train"], "val": ["biwi_hotel_val"]}
    assert 0 < cfg["train"]["val_samples"] < cfg["train"]["train_samples"] + 4000
    assert main(["evaluate", "--data", str(data), "--model", str(run), "--protocol", "eth-ucy",
                 "--out", str(tmp_path / "ev")]) == 0
    assert _metrics(tmp_path / "ev")["scene_ids"] == ["crowds_zara01"]


# ---------------------------------------------------------------------- sim-to-real: train --init
def test_train_init_fine_tunes_shipped_and_run_weights(datasets, tmp_path, capsys):
    """--init shipped starts TRAF training from the synthetic-data weights (its first validation is theirs, not a
    random network's); --init RUN continues a run; another model config is refused in one line."""
    import torch

    from predictor.predict import ModelPredictor

    traf, common = str(datasets["traf"]), ["--test-scenes", "TRAF12", "--epochs", "1", "--warmup-epochs", "1",
                                            "--max-samples", "64", "--select", "loss"]
    tuned, scratch = tmp_path / "tuned", tmp_path / "scratch"
    assert main(["train", "--data", traf, *common, "--init", "shipped", "--out", str(tuned)]) == 0
    assert main(["train", "--data", traf, *common, "--out", str(scratch)]) == 0
    cfg = json.loads((tuned / "config.json").read_text())
    shipped = ModelPredictor.shipped("traphic").model.state_dict()
    assert cfg["train"]["init"]["from"] == "shipped" and len(cfg["train"]["init"]["weights_sha256"]) == 64
    # One epoch of 64 windows moves the weights a little from the shipped ones, far less than a fresh network.
    after = ModelPredictor.from_run(tuned).model.state_dict()
    fresh = ModelPredictor.from_run(scratch).model.state_dict()
    moved = sum(float((after[k] - shipped[k]).abs().sum()) for k in shipped)
    apart = sum(float((fresh[k] - shipped[k]).abs().sum()) for k in shipped)
    assert 0 < moved < apart / 10 and all(torch.isfinite(v).all() for v in after.values())
    assert main(["train", "--data", traf, *common, "--init", str(tuned), "--out", str(tmp_path / "again")]) == 0
    assert json.loads((tmp_path / "again" / "config.json").read_text())["train"]["init"]["from"] == str(tuned)
    capsys.readouterr()
    # The paper's form is another network than the shipped residual weights.
    assert main(["train", "--data", traf, *common, "--no-residual", "--init", "shipped",
                 "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--init shipped: its model config differs" in err
    assert "residual True vs False" in err
    assert main(["train", "--data", traf, *common, "--model", "cs-lstm", "--init", str(tuned),
                 "--out", str(tmp_path / "bad2")]) == 2
    assert "model 'traphic' vs 'cs-lstm'" in capsys.readouterr().err
    assert main(["train", "--data", traf, *common, "--init", str(tmp_path / "nope"),
                 "--out", str(tmp_path / "b3")]) == 2
    assert "not a run folder" in capsys.readouterr().err
