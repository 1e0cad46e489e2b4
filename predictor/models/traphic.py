"""TraPHic (Chandra et al., CVPR 2019, section 4): the LSTM-CNN hybrid with weighted interactions.

Three layers, each agent's state Omega (predictor.features) embedded by a fully connected ELU layer
and encoded by a single-layer LSTM (hidden 64):
- horizon layer: agents of the horizon H_i, their hidden states through one more fully connected
  ELU layer (the learned weighting h_jw), pooled on the horizon grid (the horizon map), then a
  ConvNet (two 3x3 convolutions with ELU, then max-pooling) -> f_hz;
- neighbour layer: agents of the neighbourhood N_i, hidden states pooled on the neighbour grid (the
  neighbour map), then its own ConvNet -> f_nb;
- ego layer: the target's own hidden state h_i.
z = concat(h_i, f_hz, f_nb) feeds an LSTM decoder (hidden 128) that emits a bivariate Gaussian
(mu_x, mu_y, sigma_x, sigma_y, rho) per future step, in the target's frame (metres); the means are
emitted as per-step displacements and summed, sigma (a standard deviation, softplus) and rho (tanh)
directly per step.

Ablations (section 5), by two switches:
- heterogeneous: the state holds shape, type, velocity, relative velocity, concentration and
  distance (True) or positions only (False: "we do not take into account driver behavior and
  information such as shape, relative velocity, and concentration");
- horizon: the horizon layer with its weighting exists (True) or not.
TraPHic-B = neither (a plain neighbour map of positions), TraPHic-He = heterogeneous only,
TraPHic-Ho = horizon only, TraPHic = both.

Computed the fast way, the same function: only present agents are encoded; each map's first convolution
is summed from its agents' kernel taps (`_conv_map`); the decoder's constant input is projected once
(models/lstm.py). Every neighbour is still encoded in its target's frame, once per (target, neighbour).
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn
from torch.nn import functional as fn

from predictor.features import FEATURES, HOMOGENEOUS_FEATURES, NUM_FEATURES
from predictor.models.config import ModelConfig
from predictor.models.gaussian import output, zero_means
from predictor.models.lstm import constant_input_lstm

# Fixed input scales (metres, m/s, counts) so every feature is of order one.
_SCALE = {"x": 10.0, "y": 10.0, "vx": 10.0, "vy": 10.0, "concentration": 5.0, "length": 5.0, "width": 5.0,
          "rel_vx": 10.0, "rel_vy": 10.0, "distance": 10.0}


@dataclasses.dataclass(frozen=True)
class TraPHicConfig(ModelConfig):
    """Sizes and ablation switches; serialised as JSON beside the weights."""

    horizon: bool = True
    heterogeneous: bool = True
    conv1: int = 64
    conv2: int = 16
    step_scale: float = 2.0


def _encoder(d_in: int, cfg: TraPHicConfig) -> nn.ModuleDict:
    return nn.ModuleDict({"embed": nn.Linear(d_in, cfg.embed),
                          "lstm": nn.LSTM(cfg.embed, cfg.encoder, batch_first=True)})


def _convnet(cfg: TraPHicConfig) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cfg.encoder, cfg.conv1, 3, padding=1), nn.ELU(),
                         nn.Conv2d(cfg.conv1, cfg.conv2, 3, padding=1), nn.ELU(), nn.MaxPool2d(2), nn.Flatten())


class TraPHic(nn.Module):
    """forward(batch) -> (B, F, 5); batch holds tensors from `Batch.tensors()`."""

    name = "traphic"

    def __init__(self, cfg: TraPHicConfig):
        super().__init__()
        self.cfg = cfg
        cols = list(range(NUM_FEATURES)) if cfg.heterogeneous else list(HOMOGENEOUS_FEATURES)
        self.register_buffer("cols", torch.tensor(cols), persistent=False)
        scale = torch.tensor([_SCALE.get(FEATURES[c], 1.0) for c in cols])
        self.register_buffer("inv_scale", 1.0 / scale, persistent=False)
        d = len(cols)
        self.ego = _encoder(d, cfg)
        self.nbr = _encoder(d, cfg)
        self.nbr_conv = _convnet(cfg)
        gx, gy = cfg.neighbour_grid
        z = cfg.encoder + cfg.conv2 * (gx // 2) * (gy // 2)
        if cfg.horizon:
            self.hz = _encoder(d, cfg)
            self.hz_weight = nn.Linear(cfg.encoder, cfg.encoder)  # the learned weighting of horizon interactions
            self.hz_conv = _convnet(cfg)
            hx, hy = cfg.horizon_grid
            z += cfg.conv2 * (hx // 2) * (hy // 2)
        self.decoder = nn.LSTM(z, cfg.decoder, batch_first=True)
        self.out = nn.Linear(cfg.decoder, 5)
        if cfg.residual:
            zero_means(self.out)

    def _embed_weight(self, enc: nn.ModuleDict) -> torch.Tensor:
        """The embedding's weight over all NUM_FEATURES inputs with the input scales folded in (E, NUM_FEATURES):
        the ablation's unused features get zero columns, so Omega is read as is, without a copy."""
        w = enc["embed"].weight * self.inv_scale
        if w.shape[1] == NUM_FEATURES:
            return w
        return w.new_zeros(w.shape[0], NUM_FEATURES).index_copy(1, self.cols, w)

    def _encode(self, enc: nn.ModuleDict, omega: torch.Tensor) -> torch.Tensor:
        """omega (M, H, D) -> (M, encoder) last hidden state."""
        x = fn.elu(fn.linear(omega, self._embed_weight(enc), enc["embed"].bias))
        _, (h, _) = enc["lstm"](x)
        return h[0]

    def _conv_map(self, enc: nn.ModuleDict, omega: torch.Tensor, cell: torch.Tensor, grid: tuple[int, int],
                  conv: nn.Sequential, weight: nn.Linear | None) -> torch.Tensor:
        """Agents (B, K, H, D) in cells (B, K) (-1 none) -> the ConvNet's features of their map (B, F).

        The map holds the sum of the (weighted) hidden states of the agents in each cell, zero elsewhere. Its
        first convolution is computed from the agents, not the cells: a convolution is linear, so conv(map) =
        bias + the sum over agents of each kernel tap applied to the agent's state at the cell it reaches;
        with a few agents on a grid of many cells that is several times less work, and the same function.
        Only present agents are encoded.
        """
        b, k = cell.shape
        gx, gy = grid
        flat = cell.reshape(-1)
        rows = torch.nonzero(flat >= 0).squeeze(1)
        hj = self._encode(enc, omega[rows // k, rows % k])  # one gather, whatever omega's strides
        if weight is not None:
            hj = fn.elu(weight(hj))
        conv1 = conv[0]
        c_out, c_in, kx, ky = conv1.weight.shape
        px, py = conv1.padding
        # taps[n, dx, dy] = W[:, :, dx, dy] h_n, added at output cell (x - dx + px, y - dy + py); in a grid grown
        # by kx - 1 (ky - 1) cells every tap lands inside, and the conv's output is a window of it.
        taps = (hj @ conv1.weight.permute(1, 2, 3, 0).reshape(c_in, kx * ky * c_out)).view(-1, kx * ky, c_out)
        sel = flat.index_select(0, rows)
        ox = (sel // gy)[:, None] - torch.arange(kx, device=sel.device).repeat_interleave(ky) + (kx - 1)  # (n, kx * ky)
        oy = (sel % gy)[:, None] - torch.arange(ky, device=sel.device).repeat(kx) + (ky - 1)
        wx, wy = gx + kx - 1, gy + ky - 1
        slot = ((rows // k)[:, None] * wx + ox) * wy + oy
        grown = taps.new_zeros(b * wx * wy, c_out).index_add_(0, slot.reshape(-1), taps.reshape(-1, c_out))
        x0, y0 = kx - 1 - px, ky - 1 - py
        out1 = grown.view(b, wx, wy, c_out)[:, x0:x0 + gx, y0:y0 + gy] + conv1.bias
        return conv[1:](out1.permute(0, 3, 1, 2))

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        cfg = self.cfg
        parts = [self._encode(self.ego, batch["hist"])]
        if cfg.horizon:
            parts.append(self._conv_map(self.hz, batch["hz"], batch["hz_cell"], cfg.horizon_grid, self.hz_conv,
                                        self.hz_weight))
        parts.append(self._conv_map(self.nbr, batch["nbr"], batch["nbr_cell"], cfg.neighbour_grid, self.nbr_conv,
                                    None))
        z = torch.cat(parts, -1)
        o = self.out(constant_input_lstm(self.decoder, z, cfg.future))  # z at every step, projected once
        # Means as summed per-step displacements: a constant output is constant velocity, easy to start from.
        return output(o, cfg, batch["hist"], mu=torch.cumsum(o[..., :2], 1) * cfg.step_scale)
