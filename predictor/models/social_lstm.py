"""Social-LSTM (Alahi et al., CVPR 2016): per-agent LSTMs that share hidden states through social pooling.

The target and its neighbours (the agents of its neighbourhood, predictor.features) each run the same
LSTM over the history. At every step, each agent pools the previous hidden states of the other agents
on a grid centred on itself (cells of 2 * `grid_extent` / `grid` metres, axes of the target's frame),
so interactions propagate step by step through the whole group. The target's last hidden state then
drives an LSTM decoder with a bivariate Gaussian output per future step, the encoder-decoder form in
which Social-LSTM is compared on vehicle data (Deo and Trivedi, 2018).

Pooling works on the (agent, other agent) pairs of the batch (no per-agent loops, no dense grid): the social
layer's weight is split per grid cell and applied to each pair's hidden state, the same function as the layer
over the dense grid of summed hidden states, without building that mostly empty grid. Only agents present at
some history step are run, and the pairs are enumerated within each group of present agents. The recurrence
(pooling + LSTM cell, 15 steps) is one autograd function with a hand-written backward pass (`_SocialRecurrence`):
autograd would record some twenty small operations a step and keep their results; the backward pass reuses
the forward's buffers, and scatters through a sparse matmul instead of index_add (several times faster on CPU).
tests/test_pooling.py checks outputs and every parameter's gradient against the former (autograd) forms.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

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


def grid_cells(rel: torch.Tensor, grid: tuple[int, int],
               extent: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """Offsets of other agents rel (..., 2) metres -> (inside (...) bool, cell (...) int64 = along * gy + lateral,
    meaningful where inside)."""
    ix = torch.floor((rel[..., 0] + extent[0]) / (2 * extent[0]) * grid[0]).long()
    iy = torch.floor((rel[..., 1] + extent[1]) / (2 * extent[1]) * grid[1]).long()
    inside = (ix >= 0) & (ix < grid[0]) & (iy >= 0) & (iy < grid[1])
    return inside, ix * grid[1] + iy


def social_pairs(pos: torch.Tensor, present: torch.Tensor, grid: tuple[int, int],
                 extent: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """Which other agent sits in which cell of each agent's grid, at one step.

    pos (B, A, 2) metres, present (B, A) bool -> (slot (P,), source (P,)) int64 for the P pairs (i, j) with
    j != i, both present, j inside i's grid: slot = (b * A + i) * G + cell, source = b * A + j, G = gx * gy.
    """
    inside, cell = grid_cells(pos[:, None, :, :] - pos[:, :, None, :], grid, extent)  # [b, i, j]: pos_j - pos_i
    a = pos.shape[1]
    inside &= present[:, :, None] & present[:, None, :] & ~torch.eye(a, dtype=torch.bool, device=pos.device)
    b_, i_, j_ = torch.nonzero(inside, as_tuple=True)
    return (b_ * a + i_) * (grid[0] * grid[1]) + cell[b_, i_, j_], b_ * a + j_


@dataclasses.dataclass
class PairLayout:
    """The pairs of every history step of a batch, laid out for the per-cell matmuls of `_SocialRecurrence`.

    At step t the pairs fill a (G, widths[t]) buffer of cell rows, padded to the fullest cell: src[offsets[t]:
    offsets[t + 1]] (G * widths[t],) int64 is the pooled agent of each buffer row and agent[...] the pooling one,
    both row numbers 0..N-1 of the present agents, N (a row of zeros) where the buffer row is padding.
    steps[t]: whether step t has pairs. spread[t] (N, G * widths[t]): the sparse (CSR) 0/1 matrix that sums the
    buffer rows into their pooled agents (the backward pass's scatter as a matmul, several times faster than
    index_add on CPU); None at steps without pairs.
    """

    src: torch.Tensor
    agent: torch.Tensor
    offsets: list[int]
    widths: list[int]
    steps: list[bool]
    spread: list[torch.Tensor | None]


def _spread(step: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, n: int,
            sizes: list[int]) -> list[torch.Tensor | None]:
    """Per step t, the CSR matrix (n, sizes[t]) with a one at (rows[k], cols[k]) for each entry k of step step[k]
    -> list of T (None where a step has no entry)."""
    order = torch.argsort((step * n + rows) * max(sizes) + cols)  # CSR: by row, columns sorted within a row
    rows, cols = rows[order], cols[order]
    steps = len(sizes)
    per_row = torch.bincount(step * n + rows, minlength=steps * n).view(steps, n)
    crow = torch.cat([per_row.new_zeros(steps, 1), torch.cumsum(per_row, 1)], 1)
    counts = crow[:, -1].tolist()
    ones = torch.ones(max(counts), device=cols.device)
    with warnings.catch_warnings():  # torch calls its sparse CSR support beta; the matmul used here is tested
        warnings.filterwarnings("ignore", "Sparse CSR tensor support is in beta state")
        return [torch.sparse_csr_tensor(crow[t], c, ones[:k], (n, sizes[t]), check_invariants=False) if k else None
                for t, (c, k) in enumerate(zip(torch.split(cols, counts), counts, strict=True))]


class _SocialRecurrence(torch.autograd.Function):
    """The encoder's recurrence: pooling then an LSTM cell at every step, all agents at once, h_0 = c_0 = 0.

    emb (T, N, M): the embedded positions; w (4E, M + S + E): the cell's weights on [embedding, relu(social),
    h_prev] (gate order i, f, g, o), bias (4E,): both its biases; w_soc (G, E, S): the social layer per cell,
    b_soc (S,); layout: PairLayout; absent: per step, the rows (int64) of agents absent at that step, which keep
    their state, or None. -> h (N, E), the last hidden states.

    Buffers have N + 1 rows: row N is zero (what padding pools) or a sink for the padding's sums, never read back.
    The backward pass works a step at a time on buffers that stay in cache and accumulates the weights' gradients
    as it goes.
    """

    @staticmethod
    def forward(ctx: Any, emb: torch.Tensor, w: torch.Tensor, bias: torch.Tensor, w_soc: torch.Tensor,
                b_soc: torch.Tensor, layout: PairLayout, absent: list[torch.Tensor | None]) -> torch.Tensor:
        steps, n, m = emb.shape
        g, e, s = w_soc.shape
        wt = w.t()
        x_in = emb.new_empty(steps + 1, n + 1, m + s + e)  # at t: the cell's input [emb, relu(social), h_{t-1}]
        x_in[:, n] = 0.0
        x_in[0, :, m + s:] = 0.0
        x_in[:steps, :n, :m] = emb
        act = emb.new_empty(steps, n, 4, e)  # sigmoid(i), sigmoid(f), tanh(g), sigmoid(o)
        cs = emb.new_empty(steps + 1, n, e)  # c_{t-1} at t
        cs[0] = 0.0
        tc = emb.new_empty(steps, n, e)  # tanh(c_t) before absent agents are reset
        relu_b = torch.relu(b_soc)
        for t in range(steps):
            h = x_in[t, :, m + s:]
            if t and layout.steps[t]:  # at t = 0 every h is zero: the social input is the bias alone
                lo, hi, width = layout.offsets[t], layout.offsets[t + 1], layout.widths[t]
                x = h.index_select(0, layout.src[lo:hi]).view(g, width, e)
                y = torch.bmm(x, w_soc).view(g * width, s)
                soc = b_soc.expand(n + 1, s).index_add(0, layout.agent[lo:hi], y)
                torch.clamp(soc[:n], min=0.0, out=x_in[t, :n, m:m + s])
            else:
                x_in[t, :n, m:m + s] = relu_b
            a = act[t]
            torch.addmm(bias, x_in[t, :n], wt, out=a.view(n, 4 * e))
            a[:, :2].sigmoid_()
            a[:, 2].tanh_()
            a[:, 3].sigmoid_()
            c = torch.addcmul(a[:, 1] * cs[t], a[:, 0], a[:, 2], out=cs[t + 1])
            torch.mul(a[:, 3], torch.tanh(c, out=tc[t]), out=x_in[t + 1, :n, m + s:])
            ab = absent[t]
            if ab is not None:
                cs[t + 1].index_copy_(0, ab, cs[t].index_select(0, ab))
                x_in[t + 1, :, m + s:].index_copy_(0, ab, h.index_select(0, ab))
        ctx.layout, ctx.absent = layout, absent
        ctx.save_for_backward(w, w_soc, x_in, act, cs, tc)
        return x_in[steps, :n, m + s:].clone()

    @staticmethod
    def backward(ctx: Any, dout: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        w, w_soc, x_in, act, cs, tc = ctx.saved_tensors
        layout, absent = ctx.layout, ctx.absent
        steps, n = act.shape[:2]
        g, e, s = w_soc.shape
        m = x_in.shape[2] - s - e
        dgates = act.new_empty(n + 1, 4, e)
        dgates[n] = 0.0
        dg = dgates.view(n + 1, 4 * e)
        demb = act.new_empty(steps, n, m)
        dsoc = act.new_zeros(n + 1, s)
        dw, dbias, dw_soc = torch.zeros_like(w), act.new_zeros(4 * e), torch.zeros_like(w_soc)
        dsum = act.new_zeros(n, s)
        dh = dout
        dc = dout.new_zeros(n, e)
        for t in range(steps - 1, -1, -1):
            ab = absent[t]
            if ab is not None:  # absent agents pass their state's gradient straight to the previous step
                dh_ab, dc_ab = dh.index_select(0, ab), dc.index_select(0, ab)
                dh, dc = dh.index_fill(0, ab, 0.0), dc.index_fill(0, ab, 0.0)
            i, f, gg, o = act[t].unbind(1)
            tct = tc[t]
            dct = torch.addcmul(dc, dh * o, 1 - tct * tct)  # through h = o tanh(c)
            torch.mul(dct * gg, i - i * i, out=dgates[:n, 0])
            torch.mul(dct * cs[t], f - f * f, out=dgates[:n, 1])
            torch.mul(dct * i, 1 - gg * gg, out=dgates[:n, 2])
            torch.mul(dh * tct, o - o * o, out=dgates[:n, 3])
            dx_in = dg @ w  # (N + 1, M + S + E): d emb, d relu(social), d h_{t-1}
            dw.addmm_(dg.t(), x_in[t])
            dbias += dg.sum(0)
            demb[t] = dx_in[:n, :m]
            torch.mul(dx_in[:n, m:m + s], x_in[t, :n, m:m + s] > 0, out=dsoc[:n])
            dsum += dsoc[:n]
            dh = dx_in[:n, m + s:]
            if t and layout.steps[t]:  # the pooling's share: through the cell buffer to the pooled agents
                lo, hi, width = layout.offsets[t], layout.offsets[t + 1], layout.widths[t]
                dy = dsoc.index_select(0, layout.agent[lo:hi]).view(g, width, s)
                x = x_in[t, :, m + s:].index_select(0, layout.src[lo:hi]).view(g, width, e)
                dw_soc.baddbmm_(x.transpose(1, 2), dy)
                dh = torch.addmm(dh, layout.spread[t], torch.bmm(dy, w_soc.transpose(1, 2)).view(g * width, e))
            dc = dct * f
            if ab is not None:
                dh, dc = dh.index_add(0, ab, dh_ab), dc.index_add(0, ab, dc_ab)
        return demb, dw, dbias, dw_soc, dsum.sum(0), None, None


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

    def pair_layout(self, metres: torch.Tensor, present: torch.Tensor, rows: torch.Tensor) -> PairLayout:
        """The pairs of every history step among the agents `rows`.

        metres (B, A, H, 2), present (B, A, H), rows (N,) int64 sorted indices into the B * A agents (those present
        at some step) -> PairLayout over row numbers 0..N-1. Candidate pairs are the ordered pairs of distinct rows
        of the same group (a few per agent), not all A * A slots.
        """
        cfg = self.cfg
        a, steps = present.shape[1], present.shape[2]
        g = cfg.grid[0] * cfg.grid[1]
        dev = rows.device
        group = rows // a
        size = torch.bincount(group)[group]  # (N,) rows in each row's group
        start = torch.arange(rows.numel(), device=dev) - torch.searchsorted(group, group)  # rank within the group
        first = torch.arange(rows.numel(), device=dev) - start  # the group's first row
        ci = torch.repeat_interleave(torch.arange(rows.numel(), device=dev), size)
        cj = first.index_select(0, ci) + torch.arange(ci.numel(), device=dev) - torch.repeat_interleave(
            torch.cumsum(size, 0) - size, size)
        ci, cj = ci[ci != cj], cj[ci != cj]
        pos = metres.reshape(-1, steps, 2).index_select(0, rows)
        pres = present.reshape(-1, steps).index_select(0, rows)
        inside, cell = grid_cells((pos.index_select(0, cj) - pos.index_select(0, ci)).transpose(0, 1), cfg.grid,
                                  cfg.grid_extent)  # (H, C): pos_j - pos_i
        inside &= (pres.index_select(0, ci) & pres.index_select(0, cj)).t()
        t_, c_ = torch.nonzero(inside, as_tuple=True)  # step-major
        key = t_ * g + cell[t_, c_]
        order = torch.argsort(key, stable=True)
        key, c_ = key[order], c_[order]
        counts = torch.bincount(key, minlength=steps * g)
        rank = torch.arange(key.numel(), device=dev) - (torch.cumsum(counts, 0) - counts).index_select(0, key)
        per_step = counts.view(steps, g)
        widths = per_step.amax(1).clamp_min(1)
        sizes = g * widths
        offsets = torch.cat([sizes.new_zeros(1), torch.cumsum(sizes, 0)])
        step = key // g
        col = (key % g) * widths.index_select(0, step) + rank  # the pair's row in its step's buffer
        row = offsets.index_select(0, step) + col
        n = rows.numel()
        ci, cj = ci.index_select(0, c_), cj.index_select(0, c_)
        src = torch.full((int(offsets[-1]),), n, dtype=torch.long, device=dev).index_copy_(0, row, cj)
        agent = torch.full_like(src, n).index_copy_(0, row, ci)
        return PairLayout(src, agent, offsets.tolist(), widths.tolist(), (per_step.sum(1) > 0).tolist(),
                          _spread(step, cj, col, n, sizes.tolist()))

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
        layout = self.pair_layout(metres, present, rows)
        pres = present.reshape(b * a, steps).index_select(0, rows).t()  # (H, N)
        emb = fn.relu(self.embed(metres.reshape(b * a, steps, 2).index_select(0, rows).transpose(0, 1)
                                 / cfg.pos_scale))  # (H, N, embed)
        w = torch.cat([self.cell.weight_ih, self.cell.weight_hh], 1)
        w_soc = self.social.weight.view(cfg.social_embed, g, cfg.encoder).permute(1, 2, 0).contiguous()
        t_, r_ = torch.nonzero(~pres, as_tuple=True)  # step-major
        per_step = torch.bincount(t_, minlength=steps).tolist()
        absent = [ab if len(ab) else None for ab in torch.split(r_, per_step)]
        h = _SocialRecurrence.apply(emb, w, self.cell.bias_ih + self.cell.bias_hh, w_soc, self.social.bias, layout,
                                    absent)
        return omega.new_zeros(b * a, cfg.encoder).index_copy(0, rows, h).view(b, a, -1)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        group = torch.cat([batch["hist"][:, None], batch["nbr"]], 1)  # (B, 1 + K, H, D)
        h = self.encode(group)[:, 0]
        y, _ = self.decoder(h[:, None].expand(-1, self.cfg.future, -1))
        return output(self.out(y), self.cfg, batch["hist"])
