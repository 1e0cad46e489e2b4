"""Social-LSTM (Alahi et al., CVPR 2016): per-agent LSTMs that share hidden states through social pooling.

The target and its neighbours (the agents of its neighbourhood, predictor.features) each run the same
LSTM over the history. At every step, each agent pools the previous hidden states of the other agents
on a grid centred on itself (cells of 2 * `grid_extent` / `grid` metres, axes of the target's frame),
so interactions propagate step by step through the whole group. The target's last hidden state then
drives an LSTM decoder with a bivariate Gaussian output per future step, the encoder-decoder form in
which Social-LSTM is compared on vehicle data (Deo and Trivedi, 2018).

Pooling is one scatter over all (agent, other agent) pairs of the batch at once: each pair adds the
other agent's hidden state to its cell of the agent's grid.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn
from torch.nn import functional as fn

from predictor.models.config import ModelConfig
from predictor.models.gaussian import output, zero_means
from predictor.models.rnn_ed import positions


@dataclasses.dataclass(frozen=True)
class SocialLSTMConfig(ModelConfig):
    """Sizes and the pooling grid: `grid` cells (along, lateral) over +-`grid_extent` metres around each agent."""

    social_embed: int = 64
    grid: tuple[int, int] = (8, 4)
    grid_extent: tuple[float, float] = (20.0, 6.0)


def social_pairs(pos: torch.Tensor, present: torch.Tensor, grid: tuple[int, int],
                 extent: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """Which other agent sits in which cell of each agent's grid, at one step.

    pos (B, A, 2) metres, present (B, A) bool -> (slot (P,), source (P,)) int64 for the P pairs (i, j) with
    j != i, both present, j inside i's grid: slot = (b * A + i) * G + cell, source = b * A + j, G = gx * gy.
    """
    rel = pos[:, None, :, :] - pos[:, :, None, :]  # [b, i, j] = pos_j - pos_i
    ix = torch.floor((rel[..., 0] + extent[0]) / (2 * extent[0]) * grid[0]).long()
    iy = torch.floor((rel[..., 1] + extent[1]) / (2 * extent[1]) * grid[1]).long()
    a = pos.shape[1]
    inside = ((ix >= 0) & (ix < grid[0]) & (iy >= 0) & (iy < grid[1]) & present[:, :, None] & present[:, None, :]
              & ~torch.eye(a, dtype=torch.bool))
    b_, i_, j_ = torch.nonzero(inside, as_tuple=True)
    cell = ix[b_, i_, j_] * grid[1] + iy[b_, i_, j_]
    return (b_ * a + i_) * (grid[0] * grid[1]) + cell, b_ * a + j_


class SocialLSTM(nn.Module):
    """forward(batch) -> (B, F, 5) from batch["hist"] (B, H, D) and batch["nbr"] (B, K, H, D)."""

    name = "social-lstm"

    def __init__(self, cfg: SocialLSTMConfig):
        super().__init__()
        self.cfg = cfg
        g = cfg.grid[0] * cfg.grid[1]
        self.embed = nn.Linear(2, cfg.embed)
        self.social = nn.Linear(g * cfg.encoder, cfg.social_embed)
        self.cell = nn.LSTMCell(cfg.embed + cfg.social_embed, cfg.encoder)
        self.decoder = nn.LSTM(cfg.encoder, cfg.decoder, batch_first=True)
        self.out = nn.Linear(cfg.decoder, 5)
        if cfg.residual:
            zero_means(self.out)

    def encode(self, omega: torch.Tensor) -> torch.Tensor:
        """omega (B, A, H, D) of a group (row 0 the target) -> (B, A, encoder) last hidden states."""
        cfg = self.cfg
        b, a, steps = omega.shape[:3]
        g = cfg.grid[0] * cfg.grid[1]
        metres, present = positions(omega, 1.0)
        h = omega.new_zeros(b * a, cfg.encoder)
        c = omega.new_zeros(b * a, cfg.encoder)
        for t in range(steps):  # the recurrence itself is sequential; all agents of the batch at once
            pres = present[:, :, t]
            slot, src = social_pairs(metres[:, :, t], pres, cfg.grid, cfg.grid_extent)
            # Social tensor: hidden states summed per cell of each agent's grid (one scatter for the batch).
            pooled = h.new_zeros(b * a * g, cfg.encoder).index_add(0, slot, h.index_select(0, src))
            x = torch.cat([fn.relu(self.embed(metres[:, :, t] / cfg.pos_scale)).reshape(b * a, -1),
                           fn.relu(self.social(pooled.view(b * a, g * cfg.encoder)))], -1)
            h_new, c_new = self.cell(x, (h, c))
            keep = pres.reshape(-1, 1)  # absent agents keep their state
            h, c = torch.where(keep, h_new, h), torch.where(keep, c_new, c)
        return h.view(b, a, -1)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        group = torch.cat([batch["hist"][:, None], batch["nbr"]], 1)  # (B, 1 + K, H, D)
        h = self.encode(group)[:, 0]
        y, _ = self.decoder(h[:, None].expand(-1, self.cfg.future, -1))
        return output(self.out(y), self.cfg, batch["hist"])
