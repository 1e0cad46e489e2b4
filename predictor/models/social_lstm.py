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
some history step are run, and the pairs are enumerated within each group of present agents. The per-cell
matmuls pad each cell's pairs to the fullest cell of its set: the cells are split into three sets of similar
occupancy (`cell_sets`: 1.2 times the pairs instead of 1.7 with one set). The last step runs only the targets,
the only states the decoder reads. The recurrence (pooling + LSTM cell, 15 steps) is one autograd function with
a hand-written backward pass (`_SocialRecurrence`): autograd would record some twenty small operations a step and
keep their results; the backward pass reuses the forward's buffers, and scatters through a sparse matmul instead
of index_add (several times faster on CPU). tests/test_pooling.py checks outputs and every parameter's gradient
against the former (autograd) forms.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np
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


_SETS = 3  # groups of grid cells of similar occupancy, each padded to its own fullest cell


@dataclasses.dataclass
class PairLayout:
    """The pairs of every history step of a batch, laid out for the per-cell matmuls of `_SocialRecurrence`.

    The grid's cells are taken in the order `perm` (G,) int64, in sets of similar occupancy. At step t the pairs
    fill a buffer of offsets[t + 1] - offsets[t] cell rows: per set, (cells of the set, width) padded to the set's
    fullest cell. blocks[t]: per set with pairs at t, (lo, hi, c0, c1, width): buffer rows lo..hi (relative to
    offsets[t]) hold cells perm[c0:c1], `width` rows each; empty where step t has no pairs. src[offsets[t]:
    offsets[t + 1]] int64 is the pooled agent of each buffer row (row numbers 0..N-1 of the present agents; N, a
    row of zeros, for padding) and agent[...] the pooling one (at the last step a position in `final`, padding
    len(final); before it a row number, padding N). spread[t] (N, rows of step t): the sparse (CSR) 0/1 matrix
    that sums the buffer rows into their pooled agents (the backward pass's scatter as a matmul, several times
    faster than index_add on CPU); None at steps without pairs.
    """

    src: torch.Tensor
    agent: torch.Tensor
    offsets: list[int]
    blocks: list[list[tuple[int, int, int, int, int]]]
    perm: torch.Tensor
    spread: list[torch.Tensor | None]


def _stable_order(key: torch.Tensor, bound: int) -> torch.Tensor:
    """Indices that sort key (int64, values in [0, bound)) stably, sorted on the narrowest integer type that holds
    them (int16 sorts about 6 times faster than int64 on CPU)."""
    dtype = torch.int16 if bound <= 2**15 else torch.int32 if bound <= 2**31 else torch.int64
    return torch.sort(key.to(dtype), stable=True)[1]


def cell_sets(counts: np.ndarray, sets: int) -> tuple[np.ndarray, np.ndarray]:
    """The grid's cells in `sets` groups of similar occupancy, each to be padded to its own fullest cell.

    counts (T, G) pairs per step and cell -> (perm (G,) the cells ordered by their fullest step, most first;
    bounds (sets + 1,) the groups' extents in perm), the contiguous split of perm with the fewest padded rows,
    sum over steps and groups of (cells in the group) x (the group's fullest cell at that step).
    """
    g = counts.shape[1]
    perm = np.argsort(-counts.max(0), kind="stable")
    sc = counts[:, perm]
    span = np.full((g + 1, g + 1), np.inf)  # span[lo, hi]: padded rows of one group of sorted cells lo..hi-1
    for lo in range(g):
        span[lo, lo + 1:] = np.maximum.accumulate(sc[:, lo:], axis=1).sum(0) * np.arange(1, g - lo + 1)
    best, cut = span[0], []  # best[p]: fewest padded rows of the first p cells in k groups
    for _ in range(min(sets, g) - 1):
        total = best[:, None] + span  # [q, p]: the first q cells in k groups, then q..p-1 in one
        cut.append(np.argmin(total, 0))
        best = total.min(0)
    bounds = [g]
    for c in reversed(cut):
        bounds.append(int(c[bounds[-1]]))
    return perm, np.array([0, *reversed(bounds)])


def _spread(step: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, n: int,
            sizes: list[int]) -> list[torch.Tensor | None]:
    """Per step t, the CSR matrix (n, sizes[t]) with a one at (rows[k], cols[k]) for each entry k of step step[k]
    -> list of T (None where a step has no entry). The entries come in increasing cols within each step."""
    steps = len(sizes)
    order = _stable_order(step * n + rows, steps * n)  # CSR: by row, columns (increasing already) within a row
    rows, cols = rows.index_select(0, order), cols.index_select(0, order)
    per_row = torch.bincount(step * n + rows, minlength=steps * n).view(steps, n)
    crow = torch.cat([per_row.new_zeros(steps, 1), torch.cumsum(per_row, 1)], 1)
    counts = crow[:, -1].tolist()
    ones = torch.ones(max(counts), device=cols.device)
    with warnings.catch_warnings():  # torch calls its sparse CSR support beta; the matmul used here is tested
        warnings.filterwarnings("ignore", "Sparse CSR tensor support is in beta state")
        return [torch.sparse_csr_tensor(crow[t], c, ones[:k], (n, sizes[t]), check_invariants=False) if k else None
                for t, (c, k) in enumerate(zip(torch.split(cols, counts), counts, strict=True))]


def _cell(a: torch.Tensor, c_prev: torch.Tensor, c_out: torch.Tensor, tc_out: torch.Tensor,
          h_out: torch.Tensor) -> torch.Tensor:
    """One LSTM cell step. a (R, 4, E) the gates' pre-activations (torch's order i, f, g, o), activated in place;
    c_prev (R, E) -> c_out (R, E) = c_t, written like tanh(c_t) into tc_out and h_t into h_out (R, E)."""
    a[:, :2].sigmoid_()
    a[:, 2].tanh_()
    a[:, 3].sigmoid_()
    c = torch.addcmul(a[:, 1] * c_prev, a[:, 0], a[:, 2], out=c_out)
    torch.mul(a[:, 3], torch.tanh(c, out=tc_out), out=h_out)
    return c


def _cell_backward(a: torch.Tensor, c_prev: torch.Tensor, tc: torch.Tensor, dh: torch.Tensor, dc: torch.Tensor,
                   dg: torch.Tensor) -> torch.Tensor:
    """The gradient through one `_cell` step: a, c_prev, tc as it left them, dh, dc (R, E) the loss's gradient on h_t
    and c_t -> dc_{t-1} (R, E); dg (R, 4, E) gets the gradient on the gates' pre-activations. (Factors computed in
    the forward pass instead measured slower: more memory written than the backward pass saves.)"""
    i, f, g, o = a.unbind(1)
    dct = torch.addcmul(dc, dh * o, 1 - tc * tc)  # c_t's total: direct and through h_t = o tanh(c_t)
    torch.mul(dct * g, i - i * i, out=dg[:, 0])
    torch.mul(dct * c_prev, f - f * f, out=dg[:, 1])
    torch.mul(dct * i, 1 - g * g, out=dg[:, 2])
    torch.mul(dh * tc, o - o * o, out=dg[:, 3])
    return dct * f


class _SocialRecurrence(torch.autograd.Function):
    """The encoder's recurrence: pooling then an LSTM cell at every step, all agents at once, h_0 = c_0 = 0.

    emb (T, N, M): the embedded positions; w (4E, M + S + E): the cell's weights on [embedding, relu(social),
    h_prev] (torch's gate order i, f, g, o), bias (4E,): both its biases; w_soc (G, E, S): the social layer
    per cell in the layout's cell order, b_soc (S,); layout: PairLayout; absent: per step, the rows (int64) of
    agents absent at that step, which keep their state, or None (at the last step positions in `final`); final
    (K,) int64: the rows run at the last step (the decoder reads no other). -> h (K, E), their last hidden states.

    Buffers have N + 1 rows: row N is zero (what padding pools) or a sink for the padding's sums, never read back.
    The backward pass works a step at a time on buffers that stay in cache and accumulates the weights' gradients
    as it goes.
    """

    @staticmethod
    def forward(ctx: Any, emb: torch.Tensor, w: torch.Tensor, bias: torch.Tensor, w_soc: torch.Tensor,
                b_soc: torch.Tensor, layout: PairLayout, absent: list[torch.Tensor | None],
                final: torch.Tensor) -> torch.Tensor:
        steps, n, m = emb.shape
        e, s = w_soc.shape[1:]
        k, last = final.numel(), steps - 1
        wt = w.t()
        x_in = emb.new_empty(steps, n + 1, m + s + e)  # at t: the cell's input [emb, relu(social), h_{t-1}]
        x_in[:, n] = 0.0
        x_in[0, :, m + s:] = 0.0
        x_in[:, :n, :m] = emb
        x_fin = emb.new_empty(k, m + s + e)  # the same at the last step, rows `final`
        act = emb.new_empty(steps, n, 4, e)  # sigmoid(i), sigmoid(f), tanh(g), sigmoid(o)
        cs = emb.new_empty(steps + 1, n, e)  # c_{t-1} at t
        cs[0] = 0.0
        tc = emb.new_empty(steps, n, e)  # tanh(c_t) before absent agents are reset
        c_fin = emb.new_empty(2, k, e)  # at the last step: c_{t-1} of `final`, c_t
        h_fin = emb.new_empty(k, e)
        relu_b = torch.relu(b_soc)
        for t in range(steps):
            h_src = x_in[t, :, m + s:]  # (N + 1, E): h_{t-1}
            if t == last:
                cur, r, c, c_out, h_out = x_fin, k, c_fin[0], c_fin[1], h_fin
                cur[:, :m] = emb[t].index_select(0, final)
                cur[:, m + s:] = h_src.index_select(0, final)
                torch.index_select(cs[t], 0, final, out=c)
            else:
                cur, r, c, c_out, h_out = x_in[t, :n], n, cs[t], cs[t + 1], x_in[t + 1, :n, m + s:]
            if t and layout.blocks[t]:  # at t = 0 every h is zero: the social input is the bias alone
                lo, hi = layout.offsets[t], layout.offsets[t + 1]
                x = h_src.index_select(0, layout.src[lo:hi])
                y = x.new_empty(hi - lo, s)
                for b0, b1, c0, c1, width in layout.blocks[t]:
                    torch.bmm(x[b0:b1].view(c1 - c0, width, e), w_soc[c0:c1], out=y[b0:b1].view(c1 - c0, width, s))
                soc = b_soc.expand(r + 1, s).index_add(0, layout.agent[lo:hi], y)
                torch.clamp(soc[:r], min=0.0, out=cur[:, m:m + s])
            else:
                cur[:, m:m + s] = relu_b
            a = act[t, :r]
            if t:
                torch.addmm(bias, cur, wt, out=a.view(r, 4 * e))
            else:  # h_{-1} = 0
                torch.addmm(bias, cur[:, :m + s], wt[:m + s], out=a.view(r, 4 * e))
            _cell(a, c, c_out, tc[t, :r], h_out)
            ab = absent[t]
            if ab is not None:
                c_out.index_copy_(0, ab, c.index_select(0, ab))
                h_out.index_copy_(0, ab, cur[:, m + s:].index_select(0, ab))
        ctx.layout, ctx.absent, ctx.final = layout, absent, final
        ctx.save_for_backward(w, w_soc, x_in, x_fin, act, cs, tc, c_fin)
        return h_fin

    @staticmethod
    def backward(ctx: Any, dout: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        w, w_soc, x_in, x_fin, act, cs, tc, c_fin = ctx.saved_tensors
        layout, absent, final = ctx.layout, ctx.absent, ctx.final
        steps, n = act.shape[:2]
        e, s = w_soc.shape[1:]
        m = x_in.shape[2] - s - e
        k, last = final.numel(), steps - 1
        w_soc_t = w_soc.transpose(1, 2)
        dg_buf = act.new_empty(n, 4, e)
        demb = act.new_empty(steps, n, m)
        dsoc = act.new_zeros(n + 1, s)
        dw, dbias, dw_soc = torch.zeros_like(w), act.new_zeros(4 * e), torch.zeros_like(w_soc)
        dsum = act.new_zeros(n, s)
        dh, dc = dout, dout.new_zeros(k, e)
        for t in range(steps - 1, -1, -1):
            cur, r = (x_fin, k) if t == last else (x_in[t, :n], n)
            ab = absent[t]
            if ab is not None:  # absent agents pass their state's gradient straight to the previous step
                dh_ab, dc_ab = dh.index_select(0, ab), dc.index_select(0, ab)
                dh, dc = dh.index_fill(0, ab, 0.0), dc.index_fill(0, ab, 0.0)
            dg = dg_buf[:r]
            dc = _cell_backward(act[t, :r], c_fin[0] if t == last else cs[t], tc[t, :r], dh, dc, dg)
            dgf = dg.view(r, 4 * e)
            width = m + s + e if t else m + s  # h_{-1} = 0
            dx = dgf @ w[:, :width]  # (R, M + S + E): d emb, d relu(social), d h_{t-1}
            dw[:, :width].addmm_(dgf.t(), cur[:, :width])
            dbias += dgf.sum(0)
            torch.mul(dx[:, m:m + s], cur[:, m:m + s] > 0, out=dsoc[:r])
            dsum[:r] += dsoc[:r]
            if t == last:
                demb[t] = 0.0
                demb[t].index_copy_(0, final, dx[:, :m])
            else:
                demb[t] = dx[:, :m]
            if not t:
                break
            dh = dx[:, m + s:]
            if t == last:
                dh = dh.new_zeros(n, e).index_copy_(0, final, dh)
                dc = dc.new_zeros(n, e).index_copy_(0, final, dc)
                if ab is not None:
                    ab = final.index_select(0, ab)
            if layout.blocks[t]:  # the pooling's share: through the cell buffer to the pooled agents
                lo, hi = layout.offsets[t], layout.offsets[t + 1]
                dy = dsoc.index_select(0, layout.agent[lo:hi])
                x = x_in[t, :, m + s:].index_select(0, layout.src[lo:hi])
                dx_pool = x.new_empty(hi - lo, e)
                for b0, b1, c0, c1, wd in layout.blocks[t]:
                    dy_b = dy[b0:b1].view(c1 - c0, wd, s)
                    dw_soc[c0:c1].baddbmm_(x[b0:b1].view(c1 - c0, wd, e).transpose(1, 2), dy_b)
                    torch.bmm(dy_b, w_soc_t[c0:c1], out=dx_pool[b0:b1].view(c1 - c0, wd, e))
                dh = torch.addmm(dh, layout.spread[t], dx_pool)
            if ab is not None:
                dh, dc = dh.index_add(0, ab, dh_ab), dc.index_add(0, ab, dc_ab)
        return demb, dw, dbias, dw_soc, dsum.sum(0), None, None, None


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

    def pair_layout(self, metres: torch.Tensor, present: torch.Tensor, rows: torch.Tensor,
                    final: torch.Tensor) -> PairLayout:
        """The pairs of every history step among the agents `rows`, at the last step those pooled by `final`.

        metres (B, A, H, 2), present (B, A, H), rows (N,) int64 sorted indices into the B * A agents (those present
        at some step), final (K,) int64 positions in rows -> PairLayout over row numbers 0..N-1. Candidate pairs are
        the ordered pairs of distinct rows of the same group (a few per agent), not all A * A slots; none at the
        first step (every hidden state is zero there).
        """
        cfg = self.cfg
        a, steps = present.shape[1], present.shape[2]
        g = cfg.grid[0] * cfg.grid[1]
        dev = rows.device
        n = rows.numel()
        group = rows // a
        size = torch.bincount(group)[group]  # (N,) rows in each row's group
        start = torch.arange(n, device=dev) - torch.searchsorted(group, group)  # rank within the group
        first = torch.arange(n, device=dev) - start  # the group's first row
        ci = torch.repeat_interleave(torch.arange(n, device=dev), size)
        cj = first.index_select(0, ci) + torch.arange(ci.numel(), device=dev) - torch.repeat_interleave(
            torch.cumsum(size, 0) - size, size)
        other = torch.nonzero(ci != cj).squeeze(1)
        ci, cj = ci.index_select(0, other), cj.index_select(0, other)
        # offsets of the pairs from step 1 on (every hidden state is zero at step 0), in grid units
        pos = metres.reshape(-1, steps, 2).index_select(0, rows)[:, 1:].transpose(0, 1).contiguous()  # (H-1, N, 2)
        pres = present.reshape(-1, steps).index_select(0, rows)[:, 1:].t().contiguous()  # (H-1, N)
        ext, cells = pos.new_tensor(cfg.grid_extent), pos.new_tensor(cfg.grid)
        u = (pos.index_select(1, cj) - pos.index_select(1, ci) + ext) / (2 * ext) * cells  # as in grid_cells
        inside = ((u >= 0) & (u < cells)).all(2) & pres.index_select(1, ci) & pres.index_select(1, cj)
        in_final = torch.zeros(n + 1, dtype=torch.bool, device=dev).index_fill_(0, final, True)
        if steps > 1:
            inside[-1] &= in_final.index_select(0, ci)
        flat = torch.nonzero(inside.view(-1)).squeeze(1)  # step-major
        t_ = flat // ci.numel()
        c_ = flat - t_ * ci.numel()
        t_ += 1
        iu = u.view(-1, 2).index_select(0, flat).long()  # floor: u >= 0 inside
        cell_ = iu[:, 0] * cfg.grid[1] + iu[:, 1]
        counts = torch.bincount(t_ * g + cell_, minlength=steps * g).view(steps, g).cpu().numpy()
        perm, bounds = cell_sets(counts, _SETS)
        widths = np.maximum.reduceat(counts[:, perm], bounds[:-1], axis=1)  # (H, sets): each set's fullest cell
        sizes = widths * np.diff(bounds)  # buffer rows per step and set
        set_lo = np.cumsum(sizes, 1) - sizes
        offsets = np.concatenate([[0], np.cumsum(sizes.sum(1))])
        ordinal = np.empty(g, dtype=np.int64)
        ordinal[perm] = np.arange(g)  # each cell's place in perm
        which = np.repeat(np.arange(len(bounds) - 1), np.diff(bounds))  # each place's set
        key = t_ * g + torch.from_numpy(ordinal).to(dev).index_select(0, cell_)
        order = _stable_order(key, steps * g)
        key, c_ = key.index_select(0, order), c_.index_select(0, order)
        per_key = torch.bincount(key, minlength=steps * g)
        rank = torch.arange(key.numel(), device=dev) - (torch.cumsum(per_key, 0) - per_key).index_select(0, key)
        # each (step, place): the buffer row, within the step, of its cell's first pair
        base = set_lo[:, which] + (np.arange(g) - bounds[which]) * widths[:, which]
        col = torch.from_numpy(base.reshape(-1)).to(dev).index_select(0, key) + rank
        step = t_  # sorting by key kept the steps in order
        row = torch.from_numpy(offsets).to(dev).index_select(0, step) + col
        ci, cj = ci.index_select(0, c_), cj.index_select(0, c_)
        at_final = torch.full((n + 1,), -1, dtype=torch.long, device=dev).index_copy_(
            0, final, torch.arange(final.numel(), device=dev))
        tail = int(per_key[-g:].sum())  # the last step's pairs, pooled by positions in `final`
        ci[ci.numel() - tail:] = at_final.index_select(0, ci[ci.numel() - tail:])
        src = torch.full((int(offsets[-1]),), n, dtype=torch.long, device=dev).index_copy_(0, row, cj)
        agent = torch.full_like(src, n)
        agent[int(offsets[-2]):] = final.numel()
        agent.index_copy_(0, row, ci)
        blocks = [[(int(set_lo[t, k]), int(set_lo[t, k] + sizes[t, k]), int(bounds[k]), int(bounds[k + 1]),
                    int(widths[t, k])) for k in range(len(bounds) - 1) if widths[t, k]] for t in range(steps)]
        return PairLayout(src, agent, offsets.tolist(), blocks, torch.from_numpy(perm).to(dev),
                          _spread(step, cj, col, n, sizes.sum(1).tolist()))

    def encode(self, omega: torch.Tensor, every: bool = False) -> torch.Tensor:
        """omega (B, A, H, D) of a group (row 0 the target) -> (B, encoder) the targets' last hidden states, or with
        `every` (B, A, encoder) every agent's (zero for agents never present).

        The social layer over each agent's grid of summed hidden states is computed from the pairs instead: the
        grid is mostly empty, so the layer's weight is split per cell and applied to the pairs of each cell (batched
        matmuls over sets of cells of similar occupancy, pairs padded to the set's fullest cell), the same function
        for several times less work. Only agents present at some step are run: the others never update and never
        pool; at the last step only the targets (unless `every`), whose states alone the decoder reads.
        """
        cfg = self.cfg
        b, a, steps = omega.shape[:3]
        g = cfg.grid[0] * cfg.grid[1]
        metres, present = positions(omega, 1.0)
        rows = torch.nonzero(present.any(2).reshape(-1)).squeeze(1)
        final = (torch.arange(rows.numel(), device=rows.device) if every
                 else torch.nonzero(rows % a == 0).squeeze(1))
        layout = self.pair_layout(metres, present, rows, final)
        pres = present.reshape(b * a, steps).index_select(0, rows).t()  # (H, N)
        emb = fn.relu(self.embed(metres.reshape(b * a, steps, 2).index_select(0, rows).transpose(0, 1)
                                 / cfg.pos_scale))  # (H, N, embed)
        w = torch.cat([self.cell.weight_ih, self.cell.weight_hh], 1)
        w_soc = self.social.weight.view(cfg.social_embed, g, cfg.encoder).permute(1, 2, 0).index_select(
            0, layout.perm).contiguous()
        t_, r_ = torch.nonzero(~pres[:-1], as_tuple=True)  # step-major
        absent = [ab if len(ab) else None for ab in torch.split(r_, torch.bincount(t_, minlength=steps - 1).tolist())]
        ab = torch.nonzero(~pres[-1].index_select(0, final)).squeeze(1)
        absent.append(ab if len(ab) else None)
        h = _SocialRecurrence.apply(emb, w, self.cell.bias_ih + self.cell.bias_hh, w_soc,
                                    self.social.bias, layout, absent, final)
        if every:
            return omega.new_zeros(b * a, cfg.encoder).index_copy(0, rows, h).view(b, a, -1)
        return omega.new_zeros(b, cfg.encoder).index_copy(0, rows.index_select(0, final) // a, h)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        group = torch.cat([batch["hist"][:, None], batch["nbr"]], 1)  # (B, 1 + K, H, D)
        y, _ = self.decoder(self.encode(group)[:, None].expand(-1, self.cfg.future, -1))
        return output(self.out(y), self.cfg, batch["hist"])
