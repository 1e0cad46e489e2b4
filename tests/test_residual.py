"""The residual form (means = constant velocity + a learned correction): constant velocity at initialisation,
trains, and checkpoints written before the option load in the paper's form."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from _predictor_data import fit_steps, flow_scene, write_flow_dataset

from predictor.features import FeatureStore, WindowConfig
from predictor.losses import mse
from predictor.models import build_model
from predictor.models.const_vel import ConstantVelocity
from predictor.models.gaussian import cv_extrapolation
from predictor.predict import ModelPredictor
from predictor.train import train
from simharness.errors import UserError

ALL = ("traphic", "traphic-b", "rnn-ed", "social-lstm", "social-gan", "cs-lstm")


@pytest.fixture(scope="module")
def batch() -> dict[str, torch.Tensor]:
    scenes = [flow_scene(s, n=10, t=45) for s in range(2)]
    store = FeatureStore.build(scenes, ["s0", "s1"], WindowConfig())
    return store.batch(np.arange(0, len(store), 7)[:32]).tensors()


@pytest.mark.parametrize("name", ALL)
def test_residual_model_starts_as_constant_velocity(name: str) -> None:
    """Through the whole predictor (features, model, world frame), an untrained residual model forecasts what the
    constant-velocity baseline forecasts; the paper's form does not."""
    scene = flow_scene(3, n=12, t=16)
    rows = np.arange(12)
    cv = ConstantVelocity().predict(scene, rows, 25).mean
    for residual, close in ((True, True), (False, False)):
        torch.manual_seed(0)
        net = build_model(name, {"history": 15, "future": 25, "residual": residual}).eval()
        fc = ModelPredictor(net, WindowConfig(), name).predict(scene, rows, 25)
        err = np.abs(fc.mean - cv).max()
        assert (err < 1e-3) == close, (residual, err)


def test_cv_extrapolation_skips_a_missing_previous_step(batch: dict[str, torch.Tensor]) -> None:
    hist = batch["hist"].clone()
    full = cv_extrapolation(hist, 5)
    hist[:, -2] = 0.0  # one step back absent: the step before it, over two steps, gives the same constant velocity
    gap = cv_extrapolation(hist, 5)
    assert torch.allclose(full, gap, atol=0.1)  # the flow scenes' speeds change slowly
    hist[:, :-1] = 0.0  # no earlier step at all: standing still
    assert torch.equal(cv_extrapolation(hist, 5), torch.zeros_like(full))


@pytest.mark.parametrize("name", ALL)
def test_residual_model_learns_beyond_constant_velocity(name: str, batch: dict[str, torch.Tensor]) -> None:
    """The flow scenes accelerate and curve: a few steps on one batch must beat constant velocity on it."""
    torch.manual_seed(0)
    net = build_model(name, {"history": 15, "future": 25, "residual": True})
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    cv = float(mse(torch.cat([cv_extrapolation(batch["hist"], 25), torch.ones_like(batch["fut"]),
                              torch.zeros_like(batch["fut"][..., :1])], -1), batch["fut"], batch["fut_valid"]))
    fit_steps(net, batch, opt, 40)
    with torch.no_grad():
        if name == "social-gan":  # best of 4 samples, what the generator's variety loss trains
            err = ((net.sample(batch, 4, seed=1) - batch["fut"][:, None]) ** 2).sum(-1).mean(-1).min(1).values.mean()
        else:
            err = mse(net(batch), batch["fut"], batch["fut_valid"])
    # Social-GAN's noise input makes 40 steps on one batch a rougher fit: it must still beat constant velocity by 10%.
    assert float(err) < (0.9 if name == "social-gan" else 0.85) * cv, (float(err), cv)


def test_old_checkpoints_load_in_the_papers_form(tmp_path) -> None:
    """Configs without the key (runs before the option) read as residual = False, and a residual run's config
    round-trips with the key."""
    data = write_flow_dataset(tmp_path / "data", scenes=3)
    for form, residual in (("old", False), ("run", True)):
        train(data, "rnn-ed", tmp_path / form, epochs=1, warmup_epochs=1, batch_size=64, max_samples=128,
              threads=1, progress=False, model_config={"residual": residual}, cache_dir=tmp_path / "cache")
    cfg = json.loads((tmp_path / "old" / "config.json").read_text())
    del cfg["model_config"]["residual"]  # as written before the option existed
    (tmp_path / "old" / "config.json").write_text(json.dumps(cfg))
    old = ModelPredictor.from_run(tmp_path / "old")
    assert "residual" not in old.info["model_config"] and old.model.cfg.residual is False
    run = ModelPredictor.from_run(tmp_path / "run")
    assert run.info["model_config"]["residual"] is True and run.model.cfg.residual is True


def test_select_mse_keeps_only_checkpoints_with_a_fitted_sigma(tmp_path) -> None:
    """`select="mse"` picks among the epochs whose sigma the NLL phase fitted (planners read it: a warm-up
    checkpoint's untrained sigma, ~7 m everywhere, made the closed-loop ego collide) and, when fine-tuning, the
    starting weights: a fine-tuning run whose every epoch is worse on validation keeps the run it started from."""
    data = write_flow_dataset(tmp_path / "data", scenes=5)
    res = train(data, "rnn-ed", tmp_path / "ok", epochs=3, warmup_epochs=2, batch_size=64, max_samples=512,
                progress=False, select="mse", augment=True, model_config={"residual": True})
    assert res["best_epoch"] == 3  # the warm-up's epochs and the fresh start are no candidates
    assert res["config"]["train"]["select"] == "mse" and res["config"]["train"]["augment"] is True
    # A learning rate so large that every epoch ends worse than the weights it starts from.
    res = train(data, "rnn-ed", tmp_path / "hurt", epochs=2, warmup_epochs=1, batch_size=64, max_samples=256,
                lr=5.0, progress=False, select="mse", init=tmp_path / "ok", model_config={"residual": True})
    assert res["best_epoch"] == 0 and res["best_val"] == res["val_history"][0]["mse"]
    assert all(h["mse"] > res["best_val"] for h in res["val_history"][1:])
    scene = flow_scene(9, n=8, t=16)
    start = ModelPredictor.from_run(tmp_path / "ok").predict(scene, np.arange(8), 25)
    kept = ModelPredictor.from_run(tmp_path / "hurt").predict(scene, np.arange(8), 25)
    assert np.array_equal(kept.mean, start.mean) and np.array_equal(kept.sigma_rho, start.sigma_rho)


def test_select_ade_lets_a_model_without_sigma_keep_a_warm_up_epoch(tmp_path) -> None:
    """Social-GAN has no sigma for the NLL phase to fit, so `select="ade"` takes its best epoch over the whole run,
    warm-up included (the medium benchmark profile keeps its epoch 1); RNN-ED, with a sigma, only after the
    warm-up; neither keeps the fresh start."""
    data = write_flow_dataset(tmp_path / "data", scenes=5)
    kw = dict(epochs=3, warmup_epochs=2, batch_size=64, max_samples=512, lr=0.05, lr_schedule="constant",
              progress=False, select="ade", model_config={"residual": True})
    gan = train(data, "social-gan", tmp_path / "gan", **kw)
    rnn = train(data, "rnn-ed", tmp_path / "rnn", **kw)
    ade = {name: [h["ade"] for h in res["val_history"]] for name, res in (("gan", gan), ("rnn", rnn))}
    assert gan["best_epoch"] == 1 + int(np.argmin(ade["gan"][1:])) == 2  # a warm-up epoch
    assert rnn["best_epoch"] == 3 and min(ade["rnn"][1:3]) < ade["rnn"][3]  # a better warm-up epoch passed over


def test_lag_blend_starts_as_the_model_it_wraps_and_learns_to_smooth_a_jittery_velocity(batch) -> None:
    """cv_lags > 1: at initialisation exactly the residual model of cv_lags 1 (so constant velocity); on tracks whose
    last displacement is jitter around a steady motion, fitting the blend alone brings the error down."""
    from predictor.models.gaussian import LagBlend, lag_steps

    cfg = {"history": 15, "future": 25, "residual": True}
    torch.manual_seed(0)
    plain = build_model("rnn-ed", {**cfg, "cv_lags": 1})
    torch.manual_seed(0)
    blend = build_model("rnn-ed", {**cfg, "cv_lags": 5})
    assert isinstance(blend, LagBlend) and blend.name == "rnn-ed" and blend.cfg.cv_lags == 5
    assert torch.equal(plain(batch), blend(batch))
    # lag l: (now - l steps back) / l
    hist = batch["hist"].clone()
    d = lag_steps(hist, 5)
    assert d.shape == (len(hist), 4, 2)
    assert torch.allclose(d[:, 2], (hist[:, -1, :2] - hist[:, -5, :2]) / 4)
    # steady 1 m per step along x with +-0.4 m of jitter on every other position
    t = torch.arange(15, dtype=torch.float32)
    xy = torch.stack([t + 0.4 * (t % 2) - 14, torch.zeros(15)], -1)
    hist[:, :, :2] = xy
    fut = torch.stack([torch.arange(1, 26, dtype=torch.float32) + xy[-1, 0], torch.zeros(25)], -1)
    jb = {**batch, "hist": hist, "fut": fut.expand(len(hist), -1, -1).clone()}
    before = float(mse(blend(jb), jb["fut"], jb["fut_valid"]).detach())
    opt = torch.optim.Adam([blend.w], lr=1e-2)
    for _ in range(100):
        loss = mse(blend(jb), jb["fut"], jb["fut_valid"])
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.2 * before and float(blend.w.detach().abs().sum()) > 0
    with pytest.raises(UserError, match="cv_lags"):
        build_model("rnn-ed", {**cfg, "cv_lags": 15})
    assert build_model("social-gan", {**cfg, "cv_lags": 5}).cfg.cv_lags == 1


def test_cv_lags_auto_follows_the_run_it_fine_tunes(tmp_path) -> None:
    """--cv-lags auto picks a lag from the training windows (every lag up to 5 with the per-track gate), except when
    fine-tuning (--init), where the network it continues fixes the lags and the gate (and what the gate reads)."""
    from simharness.cli import main

    data = str(write_flow_dataset(tmp_path / "data", scenes=5))
    common = ["--data", data, "--model", "rnn-ed", "--epochs", "1", "--warmup-epochs", "1", "--max-samples", "64"]
    assert main(["train", *common, "--cv-lags", "3", "--out", str(tmp_path / "a")]) == 0
    assert main(["train", *common, "--init", str(tmp_path / "a"), "--out", str(tmp_path / "b")]) == 0
    cfg = json.loads((tmp_path / "b" / "config.json").read_text())
    assert cfg["model_config"]["cv_lags"] == 3 and cfg["train"]["init"]["from"] == str(tmp_path / "a")
    mc = json.loads((tmp_path / "a" / "config.json").read_text())["model_config"]
    assert mc["cv_gate"] is True and mc["cv_gate_pool"] is True
    assert main(["train", *common, "--no-cv-gate", "--out", str(tmp_path / "c")]) == 0
    mc = json.loads((tmp_path / "c" / "config.json").read_text())["model_config"]
    assert mc["cv_lags"] == 1 and mc["cv_gate"] is False  # one blend: smooth synthetic tracks want the last step
    assert main(["train", *common, "--out", str(tmp_path / "d")]) == 0  # gated (default): every lag on offer
    assert json.loads((tmp_path / "d" / "config.json").read_text())["model_config"]["cv_lags"] == 5
    assert main(["train", *common, "--init", str(tmp_path / "c"), "--out", str(tmp_path / "e")]) == 0
    assert json.loads((tmp_path / "e" / "config.json").read_text())["model_config"]["cv_gate"] is False
    assert main(["train", *common, "--no-cv-gate-pool", "--out", str(tmp_path / "f")]) == 0
    assert main(["train", *common, "--init", str(tmp_path / "f"), "--out", str(tmp_path / "g")]) == 0
    assert json.loads((tmp_path / "g" / "config.json").read_text())["model_config"]["cv_gate_pool"] is False


def test_track_jitter_tells_annotation_noise_from_a_smooth_turn() -> None:
    """White position noise: up to 2/3 (its second differences alternate; about 0.5 over 6 of them, the ratio's
    small-sample bias); a steady turn: -5/6 over 6 (they persist)."""
    from predictor.features import FEATURES
    from predictor.models.gaussian import track_jitter

    gen = torch.Generator().manual_seed(0)
    t = torch.arange(8, dtype=torch.float32)
    present = FEATURES.index("present")
    hist = torch.zeros(400, 8, len(FEATURES))
    hist[..., present] = 1.0
    hist[:200, :, 0] = t + 0.05 * torch.randn(200, 8, generator=gen)  # walking along x, clicked with 5 cm noise
    hist[:200, :, 1] = 0.05 * torch.randn(200, 8, generator=gen)
    hist[200:, :, 0], hist[200:, :, 1] = 5 * torch.sin(t / 5), 5 * (1 - torch.cos(t / 5))  # a 5 m radius turn
    j = track_jitter(hist)
    assert 0.4 < float(j[:200].mean()) < 2 / 3 and torch.allclose(j[200:], torch.full((200,), -5 / 6), atol=0.03)
    hist[:, :3, present] = 0.0  # absent steps carry no second differences
    assert torch.isfinite(track_jitter(hist)).all()


def test_pooled_jitter_reads_the_noise_of_the_agents_around_the_target(batch) -> None:
    """pooled_jitter: alone in its slots a target's own `track_jitter`; a clean turning target among noisily
    clicked neighbours reads as noisy (their shared annotation), where its own track reads as clean (the sums are
    pooled, so a sharp turn would outweigh 5 cm of noise: this one has a 20 m radius)."""
    from predictor.features import FEATURES
    from predictor.models.gaussian import pooled_jitter, track_jitter

    present = FEATURES.index("present")
    alone = {**batch, "nbr": torch.zeros_like(batch["nbr"]), "hz": torch.zeros_like(batch["hz"])}
    assert torch.allclose(pooled_jitter(alone), track_jitter(batch["hist"]), atol=1e-6)
    gen = torch.Generator().manual_seed(0)
    n, h = batch["hist"].shape[:2]
    t = torch.arange(h, dtype=torch.float32)
    hist = batch["hist"].clone()
    hist[..., 0], hist[..., 1], hist[..., present] = 20 * torch.sin(t / 20), 20 * (1 - torch.cos(t / 20)), 1.0
    nbr = torch.zeros_like(batch["nbr"])
    nbr[:, :4, :, present] = 1.0
    nbr[:, :4, :, 0] = t + 0.05 * torch.randn(n, 4, h, generator=gen)
    nbr[:, :4, :, 1] = 3.0 + 0.05 * torch.randn(n, 4, h, generator=gen)
    crowd = {**batch, "hist": hist, "nbr": nbr, "hz": torch.zeros_like(batch["hz"])}
    assert (track_jitter(hist) < -0.5).all() and (pooled_jitter(crowd) > 0.3).all()


def test_gated_lag_blend_smooths_the_noisy_tracks_and_keeps_the_turning_ones(batch) -> None:
    """cv_gate: still exactly constant velocity at the start; on a mix of noisy straight tracks (which want a long
    lag) and clean turning ones (which want the last displacement), fitting the blend per track beats the best
    blend shared by all."""
    from predictor.features import FEATURES
    from predictor.models.gaussian import LagBlend

    cfg = {"history": 15, "future": 25, "residual": True, "cv_lags": 5}
    torch.manual_seed(0)
    shared = build_model("rnn-ed", cfg)
    torch.manual_seed(0)
    gated = build_model("rnn-ed", {**cfg, "cv_gate": True})
    assert isinstance(gated, LagBlend) and gated.g is not None and shared.g is None
    assert torch.equal(shared(batch), gated(batch))
    gen = torch.Generator().manual_seed(1)
    n, t, k = len(batch["hist"]), torch.arange(-14, 26, dtype=torch.float32), len(batch["hist"]) // 2
    path = torch.stack([t, torch.zeros_like(t)], -1).expand(n, -1, -1).clone()
    path[:k, :15] += 0.3 * torch.randn(k, 15, 2, generator=gen)  # noisy clicks in the observed part
    a = (t + 14) / 12  # the turning half: clean, 1 m per step on a 12 m radius
    path[k:] = torch.stack([12 * torch.sin(a), 12 * (1 - torch.cos(a))], -1) - torch.stack(
        [12 * torch.sin(a[14]), 12 * (1 - torch.cos(a[14]))])
    hist = batch["hist"].clone()
    hist[:, :, :2], hist[:, :, FEATURES.index("present")] = path[:, :15], 1.0
    jb = {**batch, "hist": hist, "fut": path[:, 15:].clone(), "fut_valid": torch.ones(n, 25, dtype=torch.bool)}
    losses = []
    for model, params in ((shared, [shared.w]), (gated, [gated.w, gated.g])):
        opt = torch.optim.Adam(params, lr=1e-2)
        for _ in range(300):
            loss = mse(model(jb), jb["fut"], jb["fut_valid"])
            opt.zero_grad()
            loss.backward()
            opt.step()
        losses.append(float(loss.detach()))
    assert losses[1] < 0.7 * losses[0]


def test_correction_cost_keeps_the_forecasts_nearer_constant_velocity(tmp_path) -> None:
    """`correction_cost` charges each metre the means move from constant velocity: the same run with a high cost
    ends nearer constant velocity on the validation windows than without; it is recorded only when on, and refused
    where there is no correction to charge (the paper's direct form)."""
    from predictor.losses import correction
    from predictor.train import load_windows

    data = write_flow_dataset(tmp_path / "data", scenes=5)
    kw = dict(epochs=3, warmup_epochs=1, batch_size=64, max_samples=512, progress=False, select="ade",
              cache_dir=tmp_path / "c", model_config={"residual": True})
    runs = {c: train(data, "rnn-ed", tmp_path / f"c{c}", correction_cost=c, **kw) for c in (0.0, 2.0)}
    assert "correction_cost" not in runs[0.0]["config"]["train"]
    assert runs[2.0]["config"]["train"]["correction_cost"] == 2.0
    store = load_windows(data, WindowConfig(), progress=False, cache_dir=tmp_path / "c")
    b = store.batch(np.arange(len(store))).tensors()
    moved = {}
    for c in runs:
        net = ModelPredictor.from_run(tmp_path / f"c{c}").model.eval()
        with torch.no_grad():
            moved[c] = float(correction(net(b), b["hist"], b["fut_valid"]))
    assert 0 <= moved[2.0] < 0.5 * moved[0.0]
    with pytest.raises(UserError, match="correction-cost"):
        train(data, "rnn-ed", tmp_path / "direct", correction_cost=0.5, **{**kw, "model_config": {"residual": False}})
