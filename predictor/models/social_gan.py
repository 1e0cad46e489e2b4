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
error of the best of `variety_k` samples, per target) plus the adversarial loss.

A GAN gives samples, not a density: `forward` returns one sample as the mean with a placeholder sigma
(`gaussian = False` tells the predictor wrapper to report no uncertainty) and `sample` gives K futures
(best-of-20 evaluation). Evaluation noise comes from a fixed seed, so scores are reproducible.
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
    """Sizes (smaller than the original's 1024-wide MLPs, to train on a CPU), noise, loss settings."""

    mlp: int = 256
    bottleneck: int = 256
    noise_dim: int = 8
    variety_k: int = 20
    adv_weight: float = 1.0
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


def variety_loss(samples: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Best-of-K squared error: samples (B, K, F, 2), fut (B, F, 2), mask (B, F) -> scalar, m^2 per point,
    the mean over targets of the smallest per-sample mean squared error."""
    m = mask[:, None].to(samples.dtype)
    err = (((samples - fut[:, None]) ** 2).sum(-1) * m).sum(-1) / m.sum(-1).clamp_min(1)  # (B, K)
    return err.min(1).values.mean()


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
        h_n = self._encode(nbr.reshape(b * k, *nbr.shape[2:])).view(b, k, -1)
        end, present = positions(nbr[:, :, -1], self.cfg.pos_scale)  # neighbours at now, target frame (target at 0)
        feats = self.pool(torch.cat([fn.relu(self.pool_embed(end)), h_n], -1))  # (B, K, bottleneck)
        have = present & (batch["nbr_cell"] >= 0)
        pooled = feats.masked_fill(~have[..., None], float("-inf")).max(1).values
        pooled = torch.where(have.any(1, keepdim=True), pooled, torch.zeros_like(pooled))  # nobody around: zeros
        return self.context(torch.cat([h_t, pooled], -1))

    def _decode(self, ctx: torch.Tensor, hist: torch.Tensor, k: int,
                generator: torch.Generator | None = None) -> torch.Tensor:
        """ctx (B, C), hist (B, H, D) -> k sampled futures (B, k, F, 2) in metres, target frame."""
        cfg = self.cfg
        b = ctx.shape[0]
        z = torch.randn(b, k, cfg.noise_dim, generator=generator, dtype=ctx.dtype)
        h = torch.cat([ctx[:, None].expand(-1, k, -1), z], -1).reshape(b * k, -1)
        c = torch.zeros_like(h)
        xy, _ = positions(hist, 1.0)
        pos = xy[:, -1].repeat_interleave(k, 0)
        step = (xy[:, -1] - xy[:, -2]).repeat_interleave(k, 0)
        cv = cv_step(hist).repeat_interleave(k, 0) if cfg.residual else None
        out = []
        for _ in range(cfg.future):  # autoregressive: each step's input is the previous displacement
            h, c = self.cell(fn.relu(self.embed(step / cfg.disp_scale)), (h, c))
            # Residual: constant velocity's step plus a correction (zero at initialisation).
            step = self.to_step(h) * cfg.disp_scale if cv is None else cv + self.to_step(h) * cfg.residual_scale
            pos = pos + step
            out.append(pos)
        return torch.stack(out, 1).view(b, k, cfg.future, 2)

    def sample(self, batch: dict[str, torch.Tensor], k: int | None = None, seed: int | None = None) -> torch.Tensor:
        """k (default eval_samples) futures per target: (B, k, F, 2) metres, target frame; noise seeded by `seed`
        (default eval_seed) so that evaluation is reproducible."""
        gen = torch.Generator().manual_seed(self.cfg.eval_seed if seed is None else seed)
        return self._decode(self._context(batch), batch["hist"], k or self.cfg.eval_samples, gen)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """One sample as (B, F, 5): mean = the sample, sigma a 1 m placeholder, rho 0 (see `gaussian`)."""
        gen = torch.Generator().manual_seed(self.cfg.eval_seed) if not self.training else None
        xy = self._decode(self._context(batch), batch["hist"], 1, gen)[:, 0]
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
        b = fut.shape[0]
        # Generated futures are scored only where the real one is known: fill unknown steps with the truth's zeros.
        keep = mask[..., None].to(fut.dtype)
        with torch.no_grad():
            fake = self._decode(self._context(batch), batch["hist"], 1)[:, 0] * keep
        real_label, fake_label = torch.empty(b).uniform_(0.7, 1.2), torch.empty(b).uniform_(0.0, 0.3)
        d_loss = (fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, fut], 1)), real_label)
                  + fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, fake], 1)), fake_label))
        self._d_opt.zero_grad()
        d_loss.backward()
        self._d_opt.step()

        samples = self._decode(self._context(batch), batch["hist"], self.cfg.variety_k)
        adv = fn.binary_cross_entropy_with_logits(disc(torch.cat([hist_xy, samples[:, 0] * keep], 1)),
                                                  torch.empty(b).uniform_(0.7, 1.2))
        g_loss = variety_loss(samples, fut, mask) + self.cfg.adv_weight * adv
        opt.zero_grad()
        g_loss.backward()
        for p in disc.parameters():  # the generator's step must not move the discriminator
            p.grad = None
        opt.step()
        return g_loss.detach()
