"""The paper's baselines (RNN-ED, Social-LSTM, Social-GAN, CS-LSTM): shapes, masks, learning, best-of-K.

Batches come from the real feature pipeline (predictor.features) over synthetic scenes; nothing is mocked.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from _predictor_data import fit_steps

from predictor.features import FeatureStore, WindowConfig
from predictor.losses import mse
from predictor.models import MODELS, build_model
from predictor.models.social_gan import variety_loss
from predictor.models.social_lstm import social_pairs
from predictor.predict import ModelPredictor
from simharness.metrics import displacement as dm
from simharness.scene import AgentType, Scene

BASELINES = ("rnn-ed", "social-lstm", "social-gan", "cs-lstm")
GAUSSIAN = ("rnn-ed", "social-lstm", "cs-lstm")


def platoon(num_agents: int = 10, num_frames: int = 45, seed: int = 0) -> Scene:
    """Agents at 5 Hz on gently curving paths in a 40 m x 8 m patch: every agent has neighbours."""
    rng = np.random.default_rng(seed)
    t = np.arange(num_frames) * 0.2
    x0, y0 = rng.uniform(0, 40, (num_agents, 1)), rng.uniform(-4, 4, (num_agents, 1))
    v, w = rng.uniform(3, 8, (num_agents, 1)), rng.uniform(-0.3, 0.3, (num_agents, 1))
    xy = np.stack([x0 + v * t, y0 + w * t + 0.1 * np.sin(t)], -1)
    return Scene(xy=xy, heading=np.zeros((num_agents, num_frames)), speed=np.repeat(v, num_frames, 1),
                 valid=np.ones((num_agents, num_frames), bool), agent_id=[f"a{i}" for i in range(num_agents)],
                 agent_type=[AgentType(i % 7) for i in range(num_agents)], length=np.full(num_agents, 4.0),
                 width=np.full(num_agents, 1.8), dt=0.2)


@pytest.fixture(scope="module")
def batch() -> dict[str, torch.Tensor]:
    scenes = [platoon(seed=s) for s in range(2)]
    store = FeatureStore.build(scenes, ["s0", "s1"], WindowConfig())
    assert len(store) >= 16
    return store.batch(np.arange(16)).tensors()


def _model(name: str) -> torch.nn.Module:
    torch.manual_seed(0)
    return build_model(name, {"history": 15, "future": 25})


def test_baselines_are_registered() -> None:
    assert set(BASELINES) <= set(MODELS)
    for name in BASELINES:
        assert _model(name).name == name


@pytest.mark.parametrize("name", BASELINES)
def test_output_shape_and_gaussian_ranges(name: str, batch: dict[str, torch.Tensor]) -> None:
    model = _model(name).eval()
    out = model(batch)
    assert out.shape == (16, 25, 5) and torch.isfinite(out).all()
    assert (out[..., 2:4] > 0).all() and (out[..., 4].abs() < 1).all()


@pytest.mark.parametrize("name", BASELINES)
def test_absent_neighbours_are_ignored_present_ones_used(name: str, batch: dict[str, torch.Tensor]) -> None:
    model = _model(name).eval()
    ref = model(batch)
    # Garbage in the slots of absent neighbours (cell -1, present 0) must not change anything.
    junk = {k: v.clone() for k, v in batch.items()}
    absent = junk["nbr_cell"] < 0
    assert absent.any()
    junk["nbr"][absent] = torch.randn_like(junk["nbr"][absent]) * 50
    junk["nbr"][..., _present_col()] = torch.where(absent[..., None], 0.0, junk["nbr"][..., _present_col()])
    assert torch.allclose(model(junk), ref)
    # Moving the present neighbours changes a social model's forecast, and never RNN-ED's.
    moved = {k: v.clone() for k, v in batch.items()}
    have = ~absent
    moved["nbr"][..., :2] += have[..., None, None].float() * torch.tensor([3.0, 1.5])
    changed = not torch.allclose(model(moved), ref, atol=1e-5)
    assert changed == (name != "rnn-ed")


def _present_col() -> int:
    from predictor.features import FEATURES

    return FEATURES.index("present")


@pytest.mark.parametrize("name", BASELINES)
def test_loss_falls_in_a_few_steps(name: str, batch: dict[str, torch.Tensor]) -> None:
    model = _model(name)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)

    def error() -> float:  # the quantity each model is trained on, on the fixed batch
        with torch.no_grad():
            if name == "social-gan":
                return float(variety_loss(model.sample(batch, 4, seed=1), batch["fut"], batch["fut_valid"]))
            return float(mse(model(batch), batch["fut"], batch["fut_valid"]))

    before = error()
    fit_steps(model, batch, opt, 15)
    after = error()
    assert after < 0.5 * before, (before, after)


def test_social_pairs_put_each_neighbour_in_its_cell() -> None:
    pos = torch.tensor([[[0.0, 0.0], [3.0, 1.0], [100.0, 0.0], [1.0, 0.0]]])
    present = torch.tensor([[True, True, True, False]])
    slot, src = social_pairs(pos, present, grid=(8, 4), extent=(20.0, 6.0))
    # agent 1 in agent 0's grid: along floor(23/40*8) = 4, lateral floor(7/12*4) = 2 -> cell 18; and back: 3, 1 -> 13.
    pairs = sorted(zip(slot.tolist(), src.tolist(), strict=True))
    g = 8 * 4
    assert pairs == [(0 * g + 18, 1), (1 * g + 13, 0)]  # agent 2 is out of range, agent 3 absent


def test_variety_loss_is_the_best_sample() -> None:
    fut = torch.zeros(2, 3, 2)
    mask = torch.tensor([[True, True, True], [True, True, False]])
    offsets = torch.tensor([[3.0, 1.0, 2.0], [0.5, 4.0, 1.0]])  # (B, K): each sample a constant offset in x
    samples = torch.zeros(2, 3, 3, 2)
    samples[..., 0] = offsets[:, :, None]
    # Best sample per target: 1.0 (squared 1.0) and 0.5 (squared 0.25).
    assert float(variety_loss(samples, fut, mask)) == pytest.approx((1.0 + 0.25) / 2)


def test_gan_step_trains_generator_and_discriminator(batch: dict[str, torch.Tensor]) -> None:
    model = _model("social-gan")
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    gen0 = model.to_step.weight.detach().clone()
    disc0 = model.discriminator.score[1].weight.detach().clone()
    loss = model.training_step(batch, "nll", opt)
    assert torch.isfinite(loss) and not loss.requires_grad
    assert not torch.equal(model.to_step.weight, gen0)
    assert not torch.equal(model.discriminator.score[1].weight, disc0)
    # Samples differ by their noise; a seed makes them reproducible.
    model.eval()
    s1, s2 = model.sample(batch, 5, seed=3), model.sample(batch, 5, seed=3)
    assert torch.equal(s1, s2) and s1.shape == (16, 5, 25, 2)
    assert (s1[:, 0] - s1[:, 1]).abs().max() > 1e-4
    # The one evaluation forecast is the generator at the noise's mean, whatever the sampling seed.
    one = model(batch)[..., :2]
    model.cfg = dataclasses.replace(model.cfg, eval_seed=model.cfg.eval_seed + 1)
    assert torch.equal(model(batch)[..., :2], one)
    zero = torch.zeros(16, 1, model.cfg.noise_dim)
    assert torch.equal(one, model._decode(model._context(batch), batch["hist"], 1, z=zero)[:, 0])
    model.train()
    assert not torch.equal(model(batch)[..., :2], one)  # training draws the noise


def test_gan_anchor_trains_the_scored_forecast(batch: dict[str, torch.Tensor]) -> None:
    # The variety loss trains the samples' spread, not the z = 0 forecast that evaluation scores; the anchor does.
    err = {}
    for weight in (0.0, 1.0):
        model = _model("social-gan")
        model.cfg = dataclasses.replace(model.cfg, anchor_weight=weight)
        opt = torch.optim.Adam(model.parameters(), lr=3e-3)
        for _ in range(120):
            model.training_step(batch, "nll", opt)
        with torch.no_grad():
            err[weight] = float(mse(model.eval()(batch), batch["fut"], batch["fut_valid"]))
    assert err[1.0] < 0.5 * err[0.0], err


def test_gan_predictor_gives_samples_and_best_of_k_takes_the_minimum() -> None:
    torch.manual_seed(0)
    model = build_model("social-gan", {"history": 15, "future": 25, "eval_samples": 20}).eval()
    scene = platoon(seed=5)
    predictor = ModelPredictor(model, WindowConfig(), "social-gan")
    hist, truth, valid = scene.slice_frames(0, 15), scene.xy[:, 15:40], scene.valid[:, 15:40]
    rows = np.arange(scene.num_agents)
    fc = predictor.predict(hist, rows, 25)
    assert fc.sigma_rho is None  # a GAN gives samples, not a density
    assert fc.modes.shape == (len(rows), 20, 25, 2) and np.isfinite(fc.modes).all()
    # World frame: the first predicted step is near the agent's last position (untrained: within 10 m).
    assert np.abs(fc.modes[:, :, 0] - hist.xy[rows, -1][:, None]).max() < 10
    min_ade, min_fde = dm.min_ade_fde(fc.modes, truth, valid)
    per_sample_ade = np.linalg.norm(fc.modes - truth[:, None], axis=-1).mean(-1)  # (M, K)
    per_sample_fde = np.linalg.norm(fc.modes[:, :, -1] - truth[:, None, -1], axis=-1)
    assert min_ade == pytest.approx(per_sample_ade.min(1).mean(), rel=1e-6)
    assert min_fde == pytest.approx(per_sample_fde.min(1).mean(), rel=1e-6)
    assert min_ade < per_sample_ade.mean(1).mean() and min_ade <= dm.ade(fc.modes[:, 0], truth, valid)


@pytest.mark.parametrize("name", BASELINES)
def test_shipped_baselines_load_by_name_and_forecast(name: str) -> None:
    from simharness.predictors import load_predictor
    from simharness.scene import Predictor

    predictor = load_predictor(name)
    assert isinstance(predictor, Predictor)
    scene = platoon(seed=7).slice_frames(0, 15)
    fc = predictor.predict(scene, np.arange(4), 25)
    assert fc.mean.shape == (4, 25, 2) and np.isfinite(fc.mean).all()
    assert (fc.sigma_rho is None) == (name == "social-gan") and (fc.modes is not None) == (name == "social-gan")
