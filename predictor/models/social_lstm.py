"""Social-LSTM (Alahi et al., CVPR 2016): per-agent LSTMs that share hidden states through social pooling.

The target and its neighbours (the agents of its neighbourhood, predictor.features) each run the same
LSTM over the history. At every step, each agent pools the previous hidden states of the other agents
on a grid centred on itself (cells of 2 * `grid_extent` / `grid` metres, axes of the target's frame),
so interactions propagate step by step through the whole group. The target's last hidden state then
drives an LSTM decoder with a bivariate Gaussian output per future step, the encoder-decoder form in
which Social-LSTM is compared on vehicle data (Deo and Trivedi, 2018).

Pooling works on all (agent, other agent) pairs of the batch at once (no per-agent loops): the social
layer's weight is split per grid cell and applied to each pair's hidden state (`encode`), the same function
as the layer over the dense grid of summed hidden states, without building that mostly empty grid.
Only agents present at some history step are run.
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
              & ~torch.eye(a, dtype=torch.bool, device=pos.device))
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

    def pair_layout(self, metres: torch.Tensor, present: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The pairs of every history step, grouped for `encode`'s per-cell matmuls.

        metres (B, A, H, 2), present (B, A, H) -> (agent, src, slot (P,) int64, offsets (H + 1,), widths (H,)):
        pairs sorted by (step, cell); those of step t are offsets[t]:offsets[t + 1]; agent / src index the
        B * A agents; slot = cell * widths[t] + rank of the pair within its (step, cell), widths[t] the most
        pairs any cell holds at step t.
        """
        cfg = self.cfg
        b, a, steps = present.shape
        g = cfg.grid[0] * cfg.grid[1]
        slot, src = social_pairs(metres.transpose(1, 2).reshape(b * steps, a, 2),
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

    def encode(self, omega: torch.Tensor) -> torch.Tensor:
        """omega (B, A, H, D) of a group (row 0 the target) -> (B, A, encoder) last hidden states (zero for agents
        never present).

        The social layer over each agent's grid of summed hidden states is computed from the pairs instead: the
        grid is mostly empty, so the layer's weight is split per cell and applied to the pairs of each cell (one
        batched matmul over cells, pairs padded to the fullest cell), the same function for several times less
        work. Only agents present at some step are run: the others never update and never pool.
        """
        cfg = self.cfg
        b, a, steps = omega.shape[:3]
        g = cfg.grid[0] * cfg.grid[1]
        metres, present = positions(omega, 1.0)
        rows = torch.nonzero(present.any(2).reshape(-1)).squeeze(1)
        n = rows.numel()
        compact = torch.full((b * a,), -1, dtype=torch.long, device=rows.device).index_copy_(
            0, rows, torch.arange(n, device=rows.device))
        agent, src, slot, offsets, widths = self.pair_layout(metres, present)
        offsets, widths = offsets.tolist(), widths.tolist()
        agent, src = compact.index_select(0, agent), compact.index_select(0, src)
        w = self.social.weight.view(cfg.social_embed, g, cfg.encoder).permute(1, 2, 0).contiguous()  # (g, enc, soc)
        bias = self.social.bias.expand(n, -1)
        pres = present.reshape(b * a, steps).index_select(0, rows)
        emb = fn.relu(self.embed(metres.reshape(b * a, steps, 2).index_select(0, rows) / cfg.pos_scale))
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
            h_new, c_new = self.cell(torch.cat([emb[:, t], fn.relu(soc)], -1), (h, c))
            keep = pres[:, t, None]  # absent agents keep their state
            h, c = torch.where(keep, h_new, h), torch.where(keep, c_new, c)
        return omega.new_zeros(b * a, cfg.encoder).index_copy(0, rows, h).view(b, a, -1)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        group = torch.cat([batch["hist"][:, None], batch["nbr"]], 1)  # (B, 1 + K, H, D)
        h = self.encode(group)[:, 0]
        y, _ = self.decoder(h[:, None].expand(-1, self.cfg.future, -1))
        return output(self.out(y), self.cfg, batch["hist"])
