"""Social-LSTM's and Social-GAN's vectorised pooling and training step against the straightforward forms they
replace (dense grids; every sample decoded with gradients), on a small batch of the real feature pipeline."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.nn import functional as fn

from predictor.features import FEATURES, FeatureStore, WindowConfig
from predictor.losses import mse
from predictor.models import build_model
from predictor.models.gaussian import output
from predictor.models.rnn_ed import positions
from predictor.models.social_gan import variety_loss
from simharness.scene import AgentType, Scene


def _scene(seed: int, n: int = 14, t: int = 45) -> Scene:
    """Agents in a 40 m x 10 m patch, some appearing late: full and partial histories, crowded grids."""
    rng = np.random.default_rng(seed)
    time = np.arange(t) * 0.2
    xy = np.stack([rng.uniform(0, 40, (n, 1)) + rng.uniform(2, 8, (n, 1)) * time,
                   rng.uniform(-5, 5, (n, 1)) + 0.3 * np.sin(time + rng.uniform(0, 6, (n, 1)))], -1)
    valid = np.arange(t)[None] >= rng.integers(0, 20, (n, 1))
    return Scene(xy=xy, heading=np.zeros((n, t)), speed=np.full((n, t), 5.0), valid=valid,
                 agent_id=[f"a{i}" for i in range(n)], agent_type=[AgentType(i % 7) for i in range(n)],
                 length=np.full(n, 4.0), width=np.full(n, 1.8), dt=0.2)


@pytest.fixture(scope="module")
def batch() -> dict[str, torch.Tensor]:
    store = FeatureStore.build([_scene(s) for s in range(2)], ["s0", "s1"], WindowConfig())
    return store.batch(np.arange(0, len(store), 3)[:24]).tensors()


def reference_pairs(pos: torch.Tensor, present: torch.Tensor, grid: tuple[int, int],
                 extent: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """Which other agent sits in which cell of each agent's grid, at one step (the former social_pairs).

    pos (B, A, 2) metres, present (B, A) bool -> (slot (P,), source (P,)) int64 for the P pairs (i, j) with
    j != i, both present, j inside i's grid: slot = (b * A + i) * G + cell, source = b * A + j, G = gx * gy.
    """
    rel = pos[:, None, :, :] - pos[:, :, None, :]  # [b, i, j] = pos_j - pos_i
    ix = torch.floor((rel[..., 0] + extent[0]) / (2 * extent[0]) * grid[0]).long()
    iy = torch.floor((rel[..., 1] + extent[1]) / (2 * extent[1]) * grid[1]).long()
    a = pos.shape[1]
    inside = ((ix >= 0) & (ix < grid[0]) & (iy >= 0) & (iy < grid[1]) & present[:, :, None] & present[:, None, :]
              & ~torch.eye(a, dtype=torch.bool, device=pos.device))
    b_, i_, j_ = torch.nonzero(inside, as_tuple=True)
    cell = ix[b_, i_, j_] * grid[1] + iy[b_, i_, j_]
    return (b_ * a + i_) * (grid[0] * grid[1]) + cell, b_ * a + j_


def dense_encode(model: torch.nn.Module, omega: torch.Tensor) -> torch.Tensor:
    """The former Social-LSTM encoder: every agent run, hidden states summed into a dense grid per agent."""
    cfg = model.cfg
    b, a, steps = omega.shape[:3]
    g = cfg.grid[0] * cfg.grid[1]
    metres, present = positions(omega, 1.0)
    h = omega.new_zeros(b * a, cfg.encoder)
    c = omega.new_zeros(b * a, cfg.encoder)
    for t in range(steps):
        pres = present[:, :, t]
        slot, src = reference_pairs(metres[:, :, t], pres, cfg.grid, cfg.grid_extent)
        pooled = h.new_zeros(b * a * g, cfg.encoder).index_add(0, slot, h.index_select(0, src))
        x = torch.cat([fn.relu(model.embed(metres[:, :, t] / cfg.pos_scale)).reshape(b * a, -1),
                       fn.relu(model.social(pooled.view(b * a, g * cfg.encoder)))], -1)
        h_new, c_new = model.cell(x, (h, c))
        keep = pres.reshape(-1, 1)
        h, c = torch.where(keep, h_new, h), torch.where(keep, c_new, c)
    return h.view(b, a, -1)


def test_social_lstm_pooling_equals_the_dense_grid(batch: dict[str, torch.Tensor]) -> None:
    torch.manual_seed(0)
    model = build_model("social-lstm", {"history": 15, "future": 25})
    group = torch.cat([batch["hist"][:, None], batch["nbr"]], 1)
    metres, present = positions(group, 1.0)
    slot, _ = reference_pairs(metres[:, :, -1], present[:, :, -1], model.cfg.grid, model.cfg.grid_extent)
    assert slot.numel() > 2 * len(group) and not present.all(), "the batch must have crowded grids and gaps"
    new, old = model.encode(group, every=True), dense_encode(model, group)
    assert torch.allclose(new, old, atol=1e-5), float((new - old).abs().max())
    target = model.encode(group)  # the targets alone (the last step runs only them)
    assert torch.allclose(target, old[:, 0], atol=1e-5), float((target - old[:, 0]).abs().max())
    # Gradients too: the training step sees the same function.
    g_new = torch.autograd.grad(new[:, 0].square().sum(), model.social.weight)[0]
    g_old = torch.autograd.grad(dense_encode(model, group)[:, 0].square().sum(), model.social.weight)[0]
    assert torch.allclose(g_new, g_old, atol=1e-4, rtol=1e-4)


def former_pair_layout(model: torch.nn.Module, metres: torch.Tensor, present: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """The former encoder's pair layout (commit f568a54)."""
    cfg = model.cfg
    b, a, steps = present.shape
    g = cfg.grid[0] * cfg.grid[1]
    slot, src = reference_pairs(metres.transpose(1, 2).reshape(b * steps, a, 2),
                             present.transpose(1, 2).reshape(b * steps, a), cfg.grid, cfg.grid_extent)
    bt, cell = slot // (a * g), slot % g  # bt = b * H + t
    agent = (bt // steps) * a + (slot // g) % a
    src = (src // (a * steps)) * a + src % a
    key = (bt % steps) * g + cell
    order = torch.argsort(key, stable=True)
    key, agent, src, cell = key[order], agent[order], src[order], cell[order]
    counts = torch.bincount(key, minlength=steps * g)
    rank = torch.arange(key.numel(), device=key.device) - (torch.cumsum(counts, 0) - counts).index_select(0, key)
    widths = counts.view(steps, g).amax(1).clamp_min(1)
    per_step = torch.cumsum(counts.view(steps, g).sum(1), 0)
    offsets = torch.cat([torch.zeros(1, dtype=torch.long, device=key.device), per_step])
    return agent, src, cell * widths.index_select(0, key // g) + rank, offsets, widths


def former_encode(model: torch.nn.Module, omega: torch.Tensor) -> torch.Tensor:
    """Social-LSTM's encoder before the hand-written recurrence (commit f568a54), autograd through every step."""
    cfg = model.cfg
    b, a, steps = omega.shape[:3]
    g = cfg.grid[0] * cfg.grid[1]
    metres, present = positions(omega, 1.0)
    rows = torch.nonzero(present.any(2).reshape(-1)).squeeze(1)
    n = rows.numel()
    compact = torch.full((b * a,), -1, dtype=torch.long, device=rows.device).index_copy_(
        0, rows, torch.arange(n, device=rows.device))
    agent, src, slot, offsets, widths = former_pair_layout(model, metres, present)
    offsets, widths = offsets.tolist(), widths.tolist()
    agent, src = compact.index_select(0, agent), compact.index_select(0, src)
    w = model.social.weight.view(cfg.social_embed, g, cfg.encoder).permute(1, 2, 0).contiguous()  # (g, enc, soc)
    bias = model.social.bias.expand(n, -1)
    pres = present.reshape(b * a, steps).index_select(0, rows)
    emb = fn.relu(model.embed(metres.reshape(b * a, steps, 2).index_select(0, rows) / cfg.pos_scale))
    h = omega.new_zeros(n, cfg.encoder)
    c = omega.new_zeros(n, cfg.encoder)
    for t in range(steps):  # the recurrence itself is sequential; all agents of the batch at once
        lo, hi, width = offsets[t], offsets[t + 1], widths[t]
        soc = bias
        if hi > lo:
            sl = slot[lo:hi]
            x = h.new_zeros(g * width, cfg.encoder).index_copy(0, sl, h.index_select(0, src[lo:hi]))
            y = torch.bmm(x.view(g, width, -1), w).view(g * width, -1).index_select(0, sl)
            soc = bias.index_add(0, agent[lo:hi], y)
        h_new, c_new = model.cell(torch.cat([emb[:, t], fn.relu(soc)], -1), (h, c))
        keep = pres[:, t, None]  # absent agents keep their state
        h, c = torch.where(keep, h_new, h), torch.where(keep, c_new, c)
    return omega.new_zeros(b * a, cfg.encoder).index_copy(0, rows, h).view(b, a, -1)


def former_forward(model: torch.nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Social-LSTM's forward pass before the hand-written recurrences: former encoder, torch's LSTM as decoder."""
    group = torch.cat([batch["hist"][:, None], batch["nbr"]], 1)
    h = former_encode(model, group)[:, 0]
    y, _ = model.decoder(h[:, None].expand(-1, model.cfg.future, -1))
    return output(model.out(y), model.cfg, batch["hist"])


@pytest.mark.parametrize("case", ["as built", "no neighbours", "targets absent at the last step"])
def test_social_lstm_step_equals_the_former_implementation(batch: dict[str, torch.Tensor], case: str) -> None:
    """Forward outputs and the gradient of every parameter of a training loss, new encoder against the former;
    also with no pair to pool at all and with targets that keep their state at the last step."""
    present = FEATURES.index("present")
    batch = dict(batch)
    if case == "no neighbours":
        batch["nbr"] = batch["nbr"].clone()
        batch["nbr"][..., present] = 0.0
    elif case == "targets absent at the last step":
        batch["hist"] = batch["hist"].clone()
        batch["hist"][:5, -1, present] = 0.0
    torch.manual_seed(0)
    new = build_model("social-lstm", {"history": 15, "future": 25, "residual": True})
    old = build_model("social-lstm", {"history": 15, "future": 25, "residual": True})
    old.load_state_dict(new.state_dict())
    old.forward = lambda batch: former_forward(old, batch)
    with torch.no_grad():
        for p in new.out.parameters():  # the residual head starts at zero: make the means depend on the encoder
            p.normal_(0.0, 0.1)
        old.out.load_state_dict(new.out.state_dict())
    grads = []
    outs = []
    for model in (new, old):
        out = model(batch)
        mse(out, batch["fut"], batch["fut_valid"]).backward()
        outs.append(out.detach())
        grads.append({k: p.grad for k, p in model.named_parameters()})
    assert torch.allclose(outs[0], outs[1], atol=1e-5, rtol=1e-5), float((outs[0] - outs[1]).abs().max())
    for k, g_new in grads[0].items():
        g_old = grads[1][k]
        if g_old is None:  # no pair anywhere: the former graph never used the social weights
            assert case == "no neighbours" and k == "social.weight" and not g_new.any(), k
            continue
        assert g_new is not None and g_old.abs().max() > 0, k
        assert torch.allclose(g_new, g_old, atol=1e-5, rtol=1e-4), (k, float((g_new - g_old).abs().max()))


def dense_context(model: torch.nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """The former Social-GAN pooling: every neighbour slot encoded, absent ones masked before the max."""
    nbr, hist = batch["nbr"], batch["hist"]
    b, k = nbr.shape[:2]
    h_n = model._encode(nbr.reshape(b * k, *nbr.shape[2:])).view(b, k, -1)
    end, present = positions(nbr[:, :, -1], model.cfg.pos_scale)
    feats = model.pool(torch.cat([fn.relu(model.pool_embed(end)), h_n], -1))
    have = present & (batch["nbr_cell"] >= 0)
    pooled = feats.masked_fill(~have[..., None], float("-inf")).max(1).values
    pooled = torch.where(have.any(1, keepdim=True), pooled, torch.zeros_like(pooled))
    return model.context(torch.cat([model._encode(hist), pooled], -1))


def full_gan_step(model: torch.nn.Module, batch: dict[str, torch.Tensor], opt: torch.optim.Optimizer) -> torch.Tensor:
    """The former generator step: every one of the K samples decoded with gradients (same random draws), and the
    z = 0 forecast's anchor."""
    hist_xy, _ = positions(batch["hist"], 1.0)
    fut, mask = batch["fut"], batch["fut_valid"]
    disc = model.discriminator
    if model._d_opt is None:
        model._d_opt = torch.optim.Adam(disc.parameters(), lr=opt.param_groups[0]["lr"])
    b = fut.shape[0]
    keep = mask[..., None].to(fut.dtype)
    with torch.no_grad():
        fake = model._decode(dense_context(model, batch), batch["hist"], 1)[:, 0] * keep
    real_label, fake_label = torch.empty(b).uniform_(0.7, 1.2), torch.empty(b).uniform_(0.0, 0.3)
    d_loss = (fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, fut], 1)), real_label)
              + fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, fake], 1)), fake_label))
    model._d_opt.zero_grad()
    d_loss.backward()
    model._d_opt.step()
    samples = model._decode(dense_context(model, batch), batch["hist"], model.cfg.variety_k)
    adv = fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, samples[:, 0] * keep], 1)),
                                              torch.empty(b).uniform_(0.7, 1.2))
    mode = model._decode(dense_context(model, batch), batch["hist"], 1, z=torch.zeros(b, 1, model.cfg.noise_dim))
    g_loss = (variety_loss(samples, fut, mask) + model.cfg.adv_weight * adv
              + model.cfg.anchor_weight * variety_loss(mode, fut, mask))
    opt.zero_grad()
    g_loss.backward()
    for p in disc.parameters():
        p.grad = None
    opt.step()
    return g_loss.detach()


def test_social_gan_pooling_and_step_equal_the_full_forms(batch: dict[str, torch.Tensor]) -> None:
    torch.manual_seed(0)
    model = build_model("social-gan", {"history": 15, "future": 25, "variety_k": 6})
    assert 0 < int((batch["nbr_cell"] >= 0).sum()) < batch["nbr_cell"].numel()
    assert torch.allclose(model._context(batch), dense_context(model, batch), atol=1e-5)
    twin = build_model("social-gan", {"history": 15, "future": 25, "variety_k": 6})
    twin.load_state_dict(model.state_dict())
    losses, grads = [], []
    for net, step in ((model, type(model).training_step), (twin, full_gan_step)):
        opt = torch.optim.SGD(net.parameters(), lr=0.0)  # lr 0: the gradients stay to be compared
        torch.manual_seed(1)  # the same noise and labels for both
        args = (net, batch, "mse", opt) if step is not full_gan_step else (net, batch, opt)
        losses.append(float(step(*args)))
        grads.append(torch.cat([p.grad.flatten() for n, p in net.named_parameters()
                                if not n.startswith("discriminator") and p.grad is not None]))
    assert losses[0] == pytest.approx(losses[1], rel=1e-5)
    assert grads[0].shape == grads[1].shape and grads[0].abs().max() > 0
    assert torch.allclose(grads[0], grads[1], atol=1e-5, rtol=1e-4), float((grads[0] - grads[1]).abs().max())
