"""Social-GAN (Gupta et al., CVPR 2018): an LSTM generator with pooling and noise, an LSTM discriminator,
and the variety (best-of-K) loss.

Generator: an LSTM encodes the relative displacements of the target and of each neighbour; the pooling
module embeds each neighbour's position relative to the target at "now", concatenates its hidden state,
passes both through an MLP and max-pools over the neighbours; an MLP of (target state, pooled context)
plus a Gaussian noise vector (one per sample, "global" noise) initialises the decoder LSTM, which emits a
displacement per future step from the embedding of the previous one.
Discriminator: an LSTM over the target's whole trajectory (history + real or generated future) and an
MLP scoring it real or fake.

Training (`training_step`, called by predictor.train instead of the default loss): one discriminator
step (binary cross-entropy, smoothed labels), then one generator step on the variety loss (the squared
error of the best of `variety_k` samples, per target) plus the adversarial loss, plus (not in the authors'
code) `anchor_weight` x the squared error of the future at z = 0, the one forecast the harness scores: the
variety loss trains only the spread of the samples, so without it the z = 0 forecast drifted away from the
truth as training went on (validation ADE 2.77 m after the first epoch, 5.07 m after the sixth, on 14 SUMO
arterial scenes at the full profile; with it 1.92 m; docs/results.md).

A GAN gives samples, not a density: `forward` returns one future as the mean with a placeholder sigma
(`gaussian = False` tells the predictor wrapper to report no uncertainty) and `sample` gives K futures
(best-of-20 evaluation; their noise comes from a fixed seed, so scores are reproducible). In evaluation the one
future is the generator at the noise's mean (z = 0), the prior's mode: a random sample is a draw from the spread
that the variety loss trains, and at the full budget one such draw was 29% worse than constant velocity at 1 s
(0.75 m against 0.58) where z = 0 is 14% better (0.50; docs/results.md). In training it is a random draw.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn
from torch.nn import functional as fn

from predictor.models.config import ModelConfig
from predictor.models.gaussian import cv_step, zero_means
from predictor.models.rnn_ed import positions


@dataclasses.dataclass(frozen=True)
class SocialGANConfig(ModelConfig):
    """Sizes of the authors' released models (embedding 16, encoder and decoder 32, MLP 64; the paper's code
    defaults to 1024-wide MLPs), noise, loss settings (anchor_weight: the z = 0 forecast's squared error in the
    generator's loss; 0 is the authors' loss). Checkpoints record their sizes, so older, wider ones load."""

    embed: int = 16
    encoder: int = 32
    decoder: int = 32
    mlp: int = 64
    bottleneck: int = 32
    noise_dim: int = 8
    variety_k: int = 20
    adv_weight: float = 1.0
    anchor_weight: float = 1.0
    eval_samples: int = 20
    eval_seed: int = 0
    disp_scale: float = 2.0


def _mlp(*sizes: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[i], sizes[i + 1]), nn.ReLU()]
    return nn.Sequential(*layers)


def displacements(xy: torch.Tensor) -> torch.Tensor:
    """Positions (..., T, 2) -> steps (..., T, 2): xy[t] - xy[t - 1], zero at t = 0."""
    return torch.cat([torch.zeros_like(xy[..., :1, :]), xy[..., 1:, :] - xy[..., :-1, :]], -2)


def sample_errors(samples: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Each sample's mean squared error over the target's known steps: samples (B, K, F, 2), fut (B, F, 2),
    mask (B, F) -> (B, K), m^2 per point."""
    m = mask[:, None].to(samples.dtype)
    return (((samples - fut[:, None]) ** 2).sum(-1) * m).sum(-1) / m.sum(-1).clamp_min(1)


def variety_loss(samples: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Best-of-K squared error: samples (B, K, F, 2), fut (B, F, 2), mask (B, F) -> scalar, m^2 per point,
    the mean over targets of the smallest per-sample mean squared error."""
    return sample_errors(samples, fut, mask).min(1).values.mean()


class Discriminator(nn.Module):
    """LSTM over a trajectory's displacements -> one real/fake logit."""

    def __init__(self, cfg: SocialGANConfig):
        super().__init__()
        self.cfg = cfg
        self.embed = nn.Linear(2, cfg.embed)
        self.lstm = nn.LSTM(cfg.embed, cfg.encoder, batch_first=True)
        self.score = nn.Sequential(_mlp(cfg.encoder, cfg.mlp), nn.Linear(cfg.mlp, 1))

    def forward(self, traj: torch.Tensor) -> torch.Tensor:
        """traj (B, H + F, 2) metres -> (B,) logits."""
        _, (h, _) = self.lstm(fn.relu(self.embed(displacements(traj) / self.cfg.disp_scale)))
        return self.score(h[0])[:, 0]


class SocialGAN(nn.Module):
    """forward(batch) -> (B, F, 5) one sample; sample(batch, k) -> (B, K, F, 2); training_step for the GAN."""

    name = "social-gan"
    gaussian = False  # no density: the predictor wrapper reports no sigma

    def __init__(self, cfg: SocialGANConfig):
        super().__init__()
        self.cfg = cfg
        self.embed = nn.Linear(2, cfg.embed)
        self.encoder = nn.LSTM(cfg.embed, cfg.encoder, batch_first=True)
        self.pool_embed = nn.Linear(2, cfg.embed)
        self.pool = _mlp(cfg.embed + cfg.encoder, cfg.mlp, cfg.bottleneck)
        self.context = _mlp(cfg.encoder + cfg.bottleneck, cfg.mlp, cfg.decoder - cfg.noise_dim)
        self.cell = nn.LSTMCell(cfg.embed, cfg.decoder)
        self.to_step = nn.Linear(cfg.decoder, 2)
        if cfg.residual:
            zero_means(self.to_step)
        self.discriminator = Discriminator(cfg)
        self._d_opt: torch.optim.Optimizer | None = None

    # ------------------------------------------------------------------ generator
    def _encode(self, omega: torch.Tensor) -> torch.Tensor:
        """omega (M, H, D) -> (M, encoder) from the displacements."""
        xy, present = positions(omega, 1.0)
        x = fn.relu(self.embed(displacements(xy) / self.cfg.disp_scale)) * present[..., None]
        _, (h, _) = self.encoder(x)
        return h[0]

    def _context(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Target state and pooled neighbours -> (B, decoder - noise_dim)."""
        nbr, hist = batch["nbr"], batch["hist"]
        b, k = nbr.shape[:2]
        h_t = self._encode(hist)
        end, present = positions(nbr[:, :, -1], self.cfg.pos_scale)  # neighbours at now, target frame (target at 0)
        have = (present & (batch["nbr_cell"] >= 0)).reshape(-1)
        rows = torch.nonzero(have).squeeze(1)
        # Only the neighbours that are pooled are encoded and embedded (the others are masked out below).
        h_n = self._encode(nbr.reshape(b * k, *nbr.shape[2:]).index_select(0, rows))
        feats = self.pool(torch.cat([fn.relu(self.pool_embed(end.reshape(b * k, 2).index_select(0, rows))), h_n], -1))
        # Max over each target's neighbours, all at once: scatter into (B * K) rows of -inf, then max over K.
        full = feats.new_full((b * k, feats.shape[1]), float("-inf")).index_copy(0, rows, feats)
        pooled = full.view(b, k, -1).max(1).values
        pooled = torch.where(have.view(b, k).any(1, keepdim=True), pooled, torch.zeros_like(pooled))  # nobody: zeros
        return self.context(torch.cat([h_t, pooled], -1))

    def _decode(self, ctx: torch.Tensor, hist: torch.Tensor, k: int, generator: torch.Generator | None = None,
                z: torch.Tensor | None = None) -> torch.Tensor:
        """ctx (B, C), hist (B, H, D) -> k sampled futures (B, k, F, 2) in metres, target frame; z (B, k, noise)
        the noise, drawn here if None."""
        cfg = self.cfg
        b = ctx.shape[0]
        if z is None:
            # Drawn on the CPU and moved: the same seeded noise on any device.
            z = torch.randn(b, k, cfg.noise_dim, generator=generator, dtype=ctx.dtype).to(ctx.device)
        h = torch.cat([ctx[:, None].expand(-1, k, -1), z], -1).reshape(b * k, -1)
        c = torch.zeros_like(h)
        xy, _ = positions(hist, 1.0)
        pos = xy[:, -1].repeat_interleave(k, 0)
        step = (xy[:, -1] - xy[:, -2]).repeat_interleave(k, 0)
        cv = cv_step(hist).repeat_interleave(k, 0) if cfg.residual else None
        pos0 = pos
        out = []
        for t in range(cfg.future):  # autoregressive: each step's input is the previous displacement
            h, c = self.cell(fn.relu(self.embed(step / cfg.disp_scale)), (h, c))
            if cv is None:
                step = self.to_step(h) * cfg.disp_scale
            else:  # residual: constant velocity plus a correction ramped along the horizon (models.gaussian)
                new = pos0 + (t + 1) * cv + self.to_step(h) * (cfg.residual_scale * ((t + 1) / cfg.future) ** 2)
                step = new - pos
            pos = pos + step
            out.append(pos)
        return torch.stack(out, 1).view(b, k, cfg.future, 2)

    def sample(self, batch: dict[str, torch.Tensor], k: int | None = None, seed: int | None = None) -> torch.Tensor:
        """k (default eval_samples) futures per target: (B, k, F, 2) metres, target frame; noise seeded by `seed`
        (default eval_seed) so that evaluation is reproducible."""
        gen = torch.Generator().manual_seed(self.cfg.eval_seed if seed is None else seed)
        return self._decode(self._context(batch), batch["hist"], k or self.cfg.eval_samples, gen)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """One future as (B, F, 5): mean = the future at z = 0 (a random draw in training), sigma a 1 m placeholder,
        rho 0 (see `gaussian`)."""
        ctx = self._context(batch)
        z = None if self.training else ctx.new_zeros(ctx.shape[0], 1, self.cfg.noise_dim)
        xy = self._decode(ctx, batch["hist"], 1, z=z)[:, 0]
        return torch.cat([xy, torch.ones_like(xy), torch.zeros_like(xy[..., :1])], -1)

    # ------------------------------------------------------------------ training
    def training_step(self, batch: dict[str, torch.Tensor], kind: str, opt: torch.optim.Optimizer) -> torch.Tensor:
        """One discriminator step and one generator step; `opt` updates the generator (the discriminator has its
        own Adam at the same learning rate). `kind` (mse / nll warm-up) does not apply to a GAN. -> generator loss."""
        hist_xy, _ = positions(batch["hist"], 1.0)
        fut, mask = batch["fut"], batch["fut_valid"]
        disc = self.discriminator
        if self._d_opt is None:
            self._d_opt = torch.optim.Adam(disc.parameters(), lr=opt.param_groups[0]["lr"])
        for group in self._d_opt.param_groups:  # the discriminator follows the generator's learning-rate schedule
            group["lr"] = opt.param_groups[0]["lr"]
        b = fut.shape[0]
        # Generated futures are scored only where the real one is known: fill unknown steps with the truth's zeros.
        keep = mask[..., None].to(fut.dtype)
        ctx = self._context(batch)  # once: the discriminator's fake and the generator's samples share it
        with torch.no_grad():
            fake = self._decode(ctx.detach(), batch["hist"], 1)[:, 0] * keep
        real_label = torch.empty(b).uniform_(0.7, 1.2).to(fut.device)
        fake_label = torch.empty(b).uniform_(0.0, 0.3).to(fut.device)
        d_loss = (fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, fut], 1)), real_label)
                  + fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, fake], 1)), fake_label))
        self._d_opt.zero_grad()
        d_loss.backward()
        self._d_opt.step()

        # The variety loss's gradient flows through each target's best sample only: all K are decoded without
        # gradients to find it, then the best, the first (the adversarial loss's) and z = 0 (the anchor's) with them.
        z = torch.randn(b, self.cfg.variety_k, self.cfg.noise_dim, dtype=ctx.dtype).to(ctx.device)
        with torch.no_grad():
            samples = self._decode(ctx.detach(), batch["hist"], self.cfg.variety_k, z=z)
            best = sample_errors(samples, fut, mask).argmin(1)
        pick = torch.stack([z[torch.arange(b, device=z.device), best], z[:, 0], torch.zeros_like(z[:, 0])], 1)
        chosen = self._decode(ctx, batch["hist"], 3, z=pick)
        adv = fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, chosen[:, 1] * keep], 1)),
                                                  torch.empty(b).uniform_(0.7, 1.2).to(fut.device))
        err = sample_errors(chosen[:, ::2], fut, mask)  # (B, 2): the best sample's and z = 0's
        g_loss = err[:, 0].mean() + self.cfg.adv_weight * adv + self.cfg.anchor_weight * err[:, 1].mean()
        opt.zero_grad()
        g_loss.backward()
        for p in disc.parameters():  # the generator's step must not move the discriminator
            p.grad = None
        opt.step()
        return g_loss.detach()
