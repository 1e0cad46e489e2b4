"""An LSTM fed the same input at every step (TraPHic's decoder): the input projection is computed once.

`nn.LSTM(z.expand(T))` computes W_ih z + b at each of the T steps; `constant_input_lstm` computes it once
and runs only the recurrence, with the weights of an `nn.LSTM` (checkpoints are unchanged) and a
hand-written backward pass (autograd would record T small steps of ten operations each).

tanh(x) is evaluated as 2 sigmoid(2x) - 1, the same function: torch's CPU sigmoid is several times faster.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn
from torch.nn import functional as fn


class _ConstantInputLSTM(torch.autograd.Function):
    """gx (B, 4H) = W_ih z + b_ih + b_hh, w_hh (4H, H) -> h (B, T, H) for h_0 = c_0 = 0, gate order i, f, g, o."""

    @staticmethod
    def forward(ctx: Any, gx: torch.Tensor, w_hh: torch.Tensor, steps: int) -> torch.Tensor:
        b, hd = gx.shape[0], w_hh.shape[1]
        # The g gate's pre-activation doubled: one sigmoid over all four gates gives tanh(g) as 2 s - 1.
        two = torch.ones(4, 1, dtype=gx.dtype)
        two[2] = 2.0
        gx2 = (gx.view(b, 4, hd) * two).view(b, 4 * hd)
        whh2_t = (w_hh.view(4, hd, hd) * two[:, :, None]).view(4 * hd, hd).t()
        # Time-major buffers: each step reads and writes contiguous blocks.
        act = gx.new_empty(steps, b, 4, hd)  # sigmoids of i, f, 2g, o
        cs = gx.new_zeros(steps + 1, b, hd)  # c_{t-1} at t, c_t at t + 1
        tc = gx.new_empty(steps, b, hd)  # tanh(c_t)
        out = gx.new_zeros(steps + 1, b, hd)  # h_{t-1} at t, h_t at t + 1
        for t in range(steps):
            a = torch.sigmoid(torch.addmm(gx2, out[t], whh2_t), out=act[t].view(b, 4 * hd)).view(b, 4, hd)
            c = torch.addcmul(a[:, 0] * (a[:, 2] * 2 - 1), a[:, 1], cs[t], out=cs[t + 1])
            th = torch.sigmoid(c * 2, out=tc[t]).mul_(2).sub_(1)
            torch.mul(a[:, 3], th, out=out[t + 1])
        ctx.save_for_backward(w_hh, act, cs, tc, out)
        return out[1:].transpose(0, 1)

    @staticmethod
    def backward(ctx: Any, dout: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, None]:
        w_hh, act, cs, tc, out = ctx.saved_tensors
        steps, b, _, hd = act.shape
        dout = dout.transpose(0, 1)
        i, f, o = act[:, :, 0], act[:, :, 1], act[:, :, 3]
        g = act[:, :, 2] * 2 - 1
        # Everything that does not depend on the recurrence, for all steps at once.
        k_c = torch.stack([g * (i - i * i), cs[:-1] * (f - f * f), i * (1 - g * g)], 2)  # d pre_(i,f,g) / d c
        k_o = tc * (o - o * o)  # d pre_o / d h
        e = o * (1 - tc * tc)  # d c / d h
        dpre = act.new_empty(steps, b, 4, hd)
        dh = dout.new_zeros(b, hd)
        dc = dout.new_zeros(b, hd)
        for t in range(steps - 1, -1, -1):
            dh = dh + dout[t]
            dc = torch.addcmul(dc * f[t + 1] if t + 1 < steps else dc, dh, e[t])
            torch.mul(k_c[t], dc[:, None], out=dpre[t, :, :3])
            torch.mul(dh, k_o[t], out=dpre[t, :, 3])
            dh = dpre[t].view(b, 4 * hd) @ w_hh
        flat = dpre.view(steps * b, 4 * hd)
        return dpre.sum(0).view(b, 4 * hd), flat.t() @ out[:-1].reshape(steps * b, hd), None


def constant_input_lstm(lstm: nn.LSTM, z: torch.Tensor, steps: int) -> torch.Tensor:
    """The outputs of single-layer, batch-first `lstm` fed z at each of `steps` steps from a zero state.

    z (B, In) -> (B, steps, H); equals `lstm(z[:, None].expand(-1, steps, -1))[0]` (to float rounding).
    """
    if lstm.num_layers != 1 or lstm.bidirectional or not lstm.bias or lstm.proj_size:
        raise ValueError("constant_input_lstm takes a single-layer, unidirectional LSTM with biases")
    gx = fn.linear(z, lstm.weight_ih_l0, lstm.bias_ih_l0 + lstm.bias_hh_l0)
    return _ConstantInputLSTM.apply(gx, lstm.weight_hh_l0, steps)
