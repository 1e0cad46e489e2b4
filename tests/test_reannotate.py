"""Training scenes re-annotated at other noise levels: smoothing keeps straight tracks and their ends, removes
white noise and never reads across agents or gaps; noise is seeded by the scene; a training run draws its samples
from the copies, which have the same windows as their originals, and validates on the originals only."""

import numpy as np
import pytest

from predictor.features import FeatureStore, WindowConfig
from predictor.reannotate import RECORDED, copy_id, drifting, noisy, parse_levels, reannotated, simulated, smoothed
from predictor.train import _copy_table, _with_copies, open_data, train
from simharness.errors import UserError
from simharness.io.parquet import write_dataset
from simharness.scene import Scene
from tests._predictor_data import flow_scene, write_flow_dataset
from tests.conftest import make_scene


def _scene(xy: np.ndarray, valid: np.ndarray, dt: float = 0.4) -> Scene:
    return make_scene(*valid.shape, dt=dt).replace(xy=xy.astype(np.float32), valid=valid)


def test_smoothing_keeps_a_straight_track_to_its_ends_and_removes_white_noise():
    t = np.arange(60) * 0.4
    straight = np.stack([1.3 * t, 0.2 * t + 1], -1)
    truth = np.stack([2 * np.sin(0.2 * t), 0.5 * t], -1)
    noise = np.random.default_rng(0).normal(0, 0.1, truth.shape)
    valid = np.ones((2, 60), bool)
    out = smoothed(_scene(np.stack([straight, truth + noise]), valid), 0.5).xy
    assert np.abs(out[0] - straight).max() < 1e-4  # ends included: a local line, not a mean pulled inwards
    before, after = np.abs(noise).mean(), np.abs(out[1] - truth).mean()
    assert after < 0.6 * before


def test_smoothing_reads_only_an_agents_own_valid_frames():
    valid = np.zeros((3, 40), bool)
    valid[0, 5:15] = valid[0, 25:35] = True  # a track with a gap
    valid[1, :] = True
    valid[2, 20] = True  # one frame alone: nothing to fit, kept
    xy = np.zeros((3, 40, 2))
    xy[0, 5:15] = [0.0, 0.0]
    xy[0, 25:35] = [10.0, 0.0]  # a jump across the gap, and garbage where invalid
    xy[0, 15:25] = 1e6
    xy[1] = 50.0
    xy[2, 20] = [7.0, 7.0]
    out = smoothed(_scene(xy, valid), 1.0).xy
    assert np.allclose(out[0, 5:15], 0.0, atol=1e-3) and np.allclose(out[0, 25:35], [10.0, 0.0], atol=1e-3)
    assert np.allclose(out[1], 50.0) and np.allclose(out[2, 20], [7.0, 7.0])
    assert np.all(out[0, 15:25] == 1e6)  # invalid frames untouched


@pytest.mark.parametrize("kind, level, frames, tol", [("noise", 0.1, 80, 0.1), ("drift", 0.2, 200, 0.6)])
def test_reannotation_has_its_std_in_metres_is_seeded_by_scene_and_skips_invalid_frames(kind, level, frames, tol):
    scene = flow_scene(0, n=30, t=frames)
    scene = scene.replace(valid=scene.valid.copy())
    scene.valid[0, :10] = False
    a = reannotated(scene, "s", (kind, level), scale=20.0)  # 20 units per metre
    d = (a.xy - scene.xy)[scene.valid]
    assert abs(d.std() - 20.0 * level) < tol and np.all(a.xy[0, :10] == scene.xy[0, :10])
    assert np.array_equal(a.xy, reannotated(scene, "s", (kind, level), scale=20.0).xy)
    assert not np.array_equal(a.xy, reannotated(scene, "t", (kind, level), scale=20.0).xy)


def test_noise_seeds_differ_and_drift_sways_slowly():
    scene = flow_scene(0, n=30, t=200)
    assert not np.array_equal(noisy(scene, 0.1, 20.0, 1).xy, noisy(scene, 0.1, 20.0, 2).xy)
    # correlated along time, unlike white noise: consecutive frames' errors agree (the lag-1 correlation of white
    # noise is zero), so its steps are smaller than white noise's of the same std
    err = drifting(scene, 1.0, 1.0, 3).xy - scene.xy
    white = noisy(scene, 1.0, 1.0, 3).xy - scene.xy
    lag1 = float((err[:, 1:] * err[:, :-1]).mean() / (err * err).mean())
    assert lag1 > 0.6 and np.abs(np.diff(err, axis=1)).mean() < 0.6 * np.abs(np.diff(white, axis=1)).mean()


def test_levels_parse_default_by_kind_of_data_and_bad_ones_are_refused():
    assert parse_levels([0.1, 0], [0.5]) == (("smooth", 0.5), ("noise", 0.1))
    assert parse_levels([0], [0]) == ()
    assert parse_levels(None, None) == RECORDED and parse_levels(None, None, by_default=False) == ()
    assert parse_levels([0.2], None, by_default=False) == (("noise", 0.2),)
    assert parse_levels(None, None, drift=[0.2]) == (*RECORDED, ("drift", 0.2))
    assert parse_levels([0], [0], drift=[0.1, 0]) == (("drift", 0.1),)
    assert simulated({"source": "simharness generate", "backend": "sumo"})
    assert not simulated({"importer": "simharness.io.importers", "source": {"format": "traf"}})
    for noise, smooth in (([-0.1], []), ([], [float("nan")]), ([1e3], [])):
        with pytest.raises(UserError, match="re-annotation level"):
            parse_levels(noise, smooth)


def test_each_copy_has_its_originals_windows_in_the_same_order(tmp_path):
    data = write_flow_dataset(tmp_path / "data", scenes=3)
    key, ids, scenes_fn = open_data(data)
    levels = (("smooth", 0.5), ("noise", 0.2))
    key2, fn = _with_copies(key, scenes_fn, ids[:2], levels, WindowConfig())
    assert key2 != key
    scenes, sids = fn()
    assert len(scenes) == 3 + 4 and copy_id(ids[0], levels[1]) in sids and copy_id(ids[2], levels[0]) not in sids
    store = FeatureStore.build(scenes, sids, WindowConfig())
    table = _copy_table(store, ids[:2], levels)
    own = store.samples_of(ids[:2])
    assert np.all(table[own] >= 0) and np.all(table[store.samples_of(ids[2:])] == -1)
    a, b = store.batch(own).tensors(), store.batch(table[own, 1]).tensors()
    assert np.array_equal(a["fut_valid"], b["fut_valid"])
    err = (a["fut"] - b["fut"]).abs()
    assert 0.05 < float(err.mean()) < 1.0  # the same agent and frame, its positions moved by the noise


def test_training_draws_from_the_copies_and_validates_on_the_originals(tmp_path):
    data = write_flow_dataset(tmp_path / "data", scenes=5)
    kw = dict(epochs=2, warmup_epochs=2, batch_size=64, max_samples=512, threads=1, progress=False, select="mse",
              cache_dir=tmp_path / "c", model_config={"residual": True, "cv_lags": "auto", "cv_gate": True})
    plain = train(data, "traphic", tmp_path / "plain", **kw)
    res = train(data, "traphic", tmp_path / "run", reannotate=(("smooth", 0.5), ("noise", 0.3)), **kw)
    assert res["config"]["train"]["reannotate"] == ["smooth0.5s", "noise0.3m"]
    assert "reannotate" not in plain["config"]["train"]
    assert res["config"]["train"]["val_samples"] == plain["config"]["train"]["val_samples"]
    assert res["config"]["train"]["train_samples"] == plain["config"]["train"]["train_samples"] == 512
    # the same batches, some of them from the copies: other weights, still learning
    assert res["val_history"][1]["mse"] != plain["val_history"][1]["mse"]
    assert res["val_history"][-1]["mse"] < res["val_history"][0]["mse"]


def test_no_copies_where_the_history_is_too_short_for_the_gate_to_read_noise(tmp_path, capsys):
    data = write_flow_dataset(tmp_path / "data", scenes=4)
    res = train(data, "rnn-ed", tmp_path / "run", epochs=1, warmup_epochs=1, max_samples=64, threads=1,
                progress=False, window=WindowConfig(history_s=0.6, future_s=1.0), cache_dir=tmp_path / "c",
                reannotate=(("noise", 0.1),))
    assert res["config"]["frames"]["history"] == 3 and "reannotate" not in res["config"]["train"]
    assert "no re-annotated copies" in capsys.readouterr().out


def test_the_cli_copies_by_default_records_it_and_refuses_a_bad_level(tmp_path, capsys):
    import json

    from simharness.cli import main

    data = str(write_flow_dataset(tmp_path / "data", scenes=4))
    common = ["--data", data, "--model", "rnn-ed", "--epochs", "1", "--warmup-epochs", "1", "--max-samples", "64"]
    assert main(["train", *common, "--out", str(tmp_path / "a")]) == 0
    cfg = json.loads((tmp_path / "a" / "config.json").read_text())
    assert cfg["train"]["reannotate"] == ["smooth0.5s", "noise0.1m"]
    assert main(["train", *common, "--reannotate-smooth", "0", "--reannotate-noise", "0.05,0.2",
                 "--out", str(tmp_path / "b")]) == 0
    cfg = json.loads((tmp_path / "b" / "config.json").read_text())
    assert cfg["train"]["reannotate"] == ["noise0.05m", "noise0.2m"]
    assert main(["train", *common, "--reannotate-drift", "0.2", "--out", str(tmp_path / "d")]) == 0
    cfg = json.loads((tmp_path / "d" / "config.json").read_text())
    assert cfg["train"]["reannotate"] == ["smooth0.5s", "noise0.1m", "drift0.2m"]
    sim = tmp_path / "sim"
    write_dataset([flow_scene(s) for s in range(4)], sim, {"source": "simharness generate", "backend": "sumo"})
    assert main(["train", *common[2:], "--data", str(sim), "--out", str(tmp_path / "s")]) == 0
    assert "reannotate" not in json.loads((tmp_path / "s" / "config.json").read_text())["train"]  # exact positions
    for form in ("--no-residual", "--no-cv-gate"):  # no gate to read the noise level
        assert main(["train", *common, form, "--out", str(tmp_path / form)]) == 0
        assert "reannotate" not in json.loads((tmp_path / form / "config.json").read_text())["train"]
    # fine-tuning follows the run it continues: a gated one gets copies, one without a gate none
    for init, on in (("a", True), ("--no-cv-gate", False)):
        assert main(["train", *common, "--init", str(tmp_path / init), "--out", str(tmp_path / f"ft{on}")]) == 0
        assert ("reannotate" in json.loads((tmp_path / f"ft{on}" / "config.json").read_text())["train"]) is on
    capsys.readouterr()
    assert main(["train", *common, "--reannotate-noise", "-0.1", "--out", str(tmp_path / "c")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "re-annotation level" in err[0] and not (tmp_path / "c").exists()
