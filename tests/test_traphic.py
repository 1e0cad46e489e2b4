"""The TraPHic network: shapes, output ranges, ablation switches, overfitting, world-frame forecasts."""

import numpy as np
import pytest
import torch
from _predictor_data import flow_scene

from predictor.features import FEATURES, FeatureStore, WindowConfig, fill_history, to_world
from predictor.losses import mse
from predictor.models import build_model
from predictor.predict import ModelPredictor

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def store():
    return FeatureStore.build([flow_scene(0, n=20)], ["s0"], WindowConfig())


@pytest.mark.parametrize("name", ["traphic", "traphic-he", "traphic-ho", "traphic-b"])
def test_forward_shapes_and_ranges(store, name):
    torch.manual_seed(0)
    model = build_model(name, {"history": store.H, "future": store.F})
    out = model(store.batch(np.arange(9)).tensors())
    assert out.shape == (9, 25, 5)
    assert (out[..., 2:4] > 0).all() and (out[..., 4].abs() < 1).all()
    has_horizon = any(k.startswith("hz") for k in model.state_dict())
    assert has_horizon == (name in ("traphic", "traphic-ho"))


def test_heterogeneous_switch_decides_what_the_model_sees(store):
    batch = store.batch(np.arange(6)).tensors()
    changed = {k: v.clone() for k, v in batch.items()}
    t0 = FEATURES.index("type_car")
    for key in ("hist", "nbr", "hz"):  # new sizes and types, same positions
        changed[key][..., t0:t0 + 9] = changed[key][..., t0:t0 + 9].flip(-1)
        changed[key][..., FEATURES.index("length")] *= 3
    for name, sees in (("traphic", True), ("traphic-ho", False), ("traphic-b", False), ("traphic-he", True)):
        torch.manual_seed(0)
        model = build_model(name, {"history": store.H, "future": store.F})
        with torch.no_grad():
            diff = (model(batch) - model(changed)).abs().max().item()
        assert (diff > 1e-6) == sees, name


def test_overfits_a_tiny_data_set(store):
    torch.manual_seed(0)
    model = build_model("traphic", {"history": store.H, "future": store.F})
    batch = store.batch(np.arange(0, len(store), max(1, len(store) // 16))[:16]).tensors()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    first = None
    for _ in range(120):
        loss = mse(model(batch), batch["fut"], batch["fut_valid"])
        first = first if first is not None else loss.item()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < 0.05 * first


def test_predictor_forecasts_in_world_frame_for_all_agents_at_once():
    torch.manual_seed(0)
    scene = flow_scene(1, n=30, t=20)
    model = build_model("traphic", {"history": 15, "future": 25})
    pred = ModelPredictor(model.eval(), WindowConfig(), "traphic")
    rows = np.arange(30)
    fa = pred.predict(scene, rows, 25)
    theta, shift = 0.8, np.array([50.0, -20.0])
    moved = scene.replace(xy=to_world(scene.xy.astype(np.float64), shift, np.array(theta)),
                          heading=scene.heading + theta)
    fb = pred.predict(moved, rows, 25)
    assert fa.mean.shape == (30, 25, 2) and fa.sigma_rho.shape == (30, 25, 3)
    np.testing.assert_allclose(to_world(fa.mean.astype(np.float64), shift, np.array(theta)), fb.mean, atol=2e-3)
    # a rotation keeps the covariance's determinant: sx sy sqrt(1 - rho^2)
    det = lambda s: s[..., 0] * s[..., 1] * np.sqrt(1 - s[..., 2] ** 2)  # noqa: E731
    np.testing.assert_allclose(det(fa.sigma_rho), det(fb.sigma_rho), rtol=1e-3)
    assert list(fa.agent_id) == list(scene.agent_id)
    # the forecast starts near each agent's current position
    assert np.abs(fa.mean[:, 0] - scene.xy[:, -1]).max() < 30


def test_constant_input_decoder_equals_nn_lstm_fed_every_step():
    from torch import nn

    from predictor.models.lstm import constant_input_lstm

    torch.manual_seed(1)
    lstm = nn.LSTM(7, 5, batch_first=True)
    z = torch.randn(4, 7, requires_grad=True)
    w = torch.randn(4, 6, 5)
    want, _ = lstm(z[:, None].expand(-1, 6, -1))
    got = constant_input_lstm(lstm, z, 6)
    torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
    grads_want = torch.autograd.grad((want * w).sum(), [z, *lstm.parameters()])
    grads_got = torch.autograd.grad((got * w).sum(), [z, *lstm.parameters()])
    for a, b in zip(grads_got, grads_want, strict=True):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-4)
    lstm64 = nn.LSTM(3, 2, batch_first=True).double()
    assert torch.autograd.gradcheck(lambda x: constant_input_lstm(lstm64, x, 4),
                                    (torch.randn(2, 3, dtype=torch.float64, requires_grad=True),))


@pytest.mark.parametrize("layer", ["nbr", "hz"])
def test_first_convolution_from_the_agents_equals_the_dense_map(store, layer):
    """The model convolves the map agent by agent; the paper's form builds the map, then convolves it."""
    torch.manual_seed(2)
    model = build_model("traphic", {"history": store.H, "future": store.F})
    batch = store.batch(np.arange(0, len(store), 7)).tensors()
    enc, conv = getattr(model, layer), getattr(model, f"{layer}_conv")
    grid = model.cfg.neighbour_grid if layer == "nbr" else model.cfg.horizon_grid
    weight = model.hz_weight if layer == "hz" else None
    omega, cell = batch[layer], batch[f"{layer}_cell"]
    assert (cell >= 0).sum() > 20 and len(set(cell[cell >= 0].tolist())) > 5  # agents in many cells, edges too
    with torch.no_grad():
        got = model._conv_map(enc, omega, cell, grid, conv, weight)
        dense = torch.zeros(cell.shape[0], model.cfg.encoder, grid[0] * grid[1])
        for i, j in zip(*np.nonzero(cell.numpy() >= 0), strict=True):  # the map, cell by cell, as in the paper
            h = model._encode(enc, omega[i, j][None])
            dense[i, :, cell[i, j]] += (torch.nn.functional.elu(weight(h)) if weight is not None else h)[0]
        want = conv(dense.view(-1, model.cfg.encoder, *grid))
    torch.testing.assert_close(got, want, atol=2e-5, rtol=1e-4)


def _straight(n: int = 8, t: int = 15, dt: float = 0.2):
    """n agents at constant velocity along x (its own speed each), 1.5 m apart laterally."""
    from simharness.scene import Scene

    speed = np.linspace(3.0, 12.0, n)
    x = speed[:, None] * np.arange(t)[None] * dt + np.linspace(0, 40, n)[:, None]
    xy = np.stack([x, np.repeat(np.linspace(-5, 5, n)[:, None], t, 1)], -1)
    return Scene(xy=xy, heading=np.zeros((n, t)), speed=np.repeat(speed[:, None], t, 1), valid=np.ones((n, t), bool),
                 agent_id=[f"a{i}" for i in range(n)], agent_type=np.arange(n) % 8, length=np.full(n, 4.0),
                 width=np.full(n, 1.8), dt=dt)


def test_fill_history_extrapolates_back_at_constant_velocity_for_the_targets_only():
    full = _straight()
    short = full.slice_frames(12)  # the last 3 frames only
    short = short.replace(valid=short.valid.copy(), speed=short.speed.copy())
    short.valid[0, 0] = False  # agent 0 seen for two frames, agent 1 for one, agent 4 for one and standing
    short.valid[1, :2] = False
    short.valid[4, :2] = False
    short.speed[4] = 0.0
    filled = fill_history(short, 15, np.array([0, 1, 2, 4]))
    assert filled.num_frames == 15 and filled.valid[[0, 1, 2, 4]].all()
    np.testing.assert_allclose(filled.xy[0], full.xy[0], atol=1e-4)  # back along its own velocity
    np.testing.assert_allclose(filled.xy[1], full.xy[1], atol=1e-4)  # back at its recorded speed and heading
    np.testing.assert_allclose(filled.xy[4], np.repeat(full.xy[4, -1:], 15, 0))  # recorded standing: held still
    np.testing.assert_allclose(filled.xy[2], full.xy[2], atol=1e-4)
    assert not filled.valid[3, :12].any()  # not a target: left as recorded (padded)
    assert fill_history(full, 15, np.arange(8)).xy is full.xy  # full histories: nothing to do


def test_a_short_history_forecasts_like_the_full_one():
    """A target seen for a few frames (just appeared, or the first seconds of a closed-loop episode) gets the
    forecast of its constant-velocity history; the model was trained on full histories only."""
    torch.manual_seed(0)
    model = build_model("traphic", {"history": 15, "future": 25}).eval()
    pred = ModelPredictor(model, WindowConfig(), "traphic")
    full = _straight()
    rows = np.arange(8)
    fa = pred.predict(full, rows, 25)
    fb = pred.predict(full.slice_frames(13), rows, 25)  # two frames of history
    np.testing.assert_allclose(fb.mean, fa.mean, atol=1e-3)
    fc = pred.predict(full.slice_frames(14), rows, 25)  # one frame (an agent that has just come in): its speed
    np.testing.assert_allclose(fc.mean, fa.mean, atol=1e-3)
