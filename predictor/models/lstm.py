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
        # The g gate's pre-activation doubled: one sigmoid over all four gates gives tanh(g) as 2 u - 1.
        two = torch.ones(4, 1, dtype=gx.dtype, device=gx.device)
        two[2] = 2.0
        gx2 = (gx.view(b, 4, hd) * two).view(b, 4 * hd)
        whh2_t = (w_hh.view(4, hd, hd) * two[:, :, None]).view(4 * hd, hd).t()
        neg = torch.tensor([-2.0, 0.0, 0.0, -1.0], dtype=gx.dtype, device=gx.device)[:, None]
        # Time-major buffers: each step reads and writes contiguous blocks. The cell state is kept doubled (c2 = 2c)
        # so that tanh(c) = 2 sigmoid(c2) - 1 needs no scaling: seven operations a step.
        act = gx.new_empty(steps, b, 4, hd)  # sigmoid of i, f, 2g, o
        c2 = gx.new_zeros(steps + 1, b, hd)  # 2 c_{t-1} at t, 2 c_t at t + 1
        sc = gx.new_empty(steps, b, hd)  # sigmoid(2 c_t)
        out = gx.new_zeros(steps + 1, b, hd)  # h_{t-1} at t, h_t at t + 1
        for t in range(steps):
            a = torch.sigmoid(torch.addmm(gx2, out[t], whh2_t), out=act[t].view(b, 4 * hd)).view(b, 4, hd)
            m = a * neg  # -2 i and -o
            # 2 c = f 2 c_prev + 2 i g, with g = 2 u - 1: 2 i g = 4 i u - 2 i
            c = torch.addcmul(torch.addcmul(m[:, 0], a[:, 0], a[:, 2], value=4.0), a[:, 1], c2[t], out=c2[t + 1])
            s = torch.sigmoid(c, out=sc[t])
            torch.addcmul(m[:, 3], a[:, 3], s, value=2.0, out=out[t + 1])  # h = o tanh(c) = 2 o s - o
        ctx.save_for_backward(w_hh, act, c2, sc, out)
        return out[1:].transpose(0, 1)

    @staticmethod
    def backward(ctx: Any, dout: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, None]:
        w_hh, act, c2, sc, out = ctx.saved_tensors
        steps, b, _, hd = act.shape
        dout = dout.transpose(0, 1)
        i, f, o = act[:, :, 0], act[:, :, 1], act[:, :, 3]
        g = act[:, :, 2] * 2 - 1
        cs, tc = c2 * 0.5, sc * 2 - 1
        # Everything that does not depend on the recurrence, for all steps at once.
        k_c = torch.stack([g * (i - i * i), cs[:-1] * (f - f * f), i * (1 - g * g)], 2)  # d pre_(i,f,g) / d c
        k_o = tc * (o - o * o)  # d pre_o / d h
        e = o * (1 - tc * tc)  # d c / d h
        dpre = act.new_empty(steps, b, 4, hd)
        dh = dout[steps - 1]
        dc = dout.new_zeros(b, hd)
        for t in range(steps - 1, -1, -1):
            dc = torch.addcmul(dc * f[t + 1] if t + 1 < steps else dc, dh, e[t])
            torch.mul(k_c[t], dc[:, None], out=dpre[t, :, :3])
            torch.mul(dh, k_o[t], out=dpre[t, :, 3])
            if t:  # dh_{t-1}: the output's gradient plus what flows back through the recurrence
                dh = torch.addmm(dout[t - 1], dpre[t].view(b, 4 * hd), w_hh)
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
