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
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torch import nn
from torch.nn import functional as fn

from predictor.features import FEATURES, HOMOGENEOUS_FEATURES, NUM_FEATURES

# Fixed input scales (metres, m/s, counts) so every feature is of order one.
_SCALE = {"x": 10.0, "y": 10.0, "vx": 10.0, "vy": 10.0, "concentration": 5.0, "length": 5.0, "width": 5.0,
          "rel_vx": 10.0, "rel_vy": 10.0, "distance": 10.0}


@dataclasses.dataclass(frozen=True)
class TraPHicConfig:
    """Sizes and ablation switches; serialised as JSON beside the weights."""

    horizon: bool = True
    heterogeneous: bool = True
    history: int = 15
    future: int = 25
    embed: int = 32
    encoder: int = 64
    decoder: int = 128
    conv1: int = 64
    conv2: int = 16
    neighbour_grid: tuple[int, int] = (13, 5)
    horizon_grid: tuple[int, int] = (7, 5)
    max_neighbours: int = 12
    max_horizon: int = 6
    pos_scale: float = 10.0
    step_scale: float = 2.0

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


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

    def _encode(self, enc: nn.ModuleDict, omega: torch.Tensor) -> torch.Tensor:
        """omega (M, H, D) -> (M, encoder) last hidden state."""
        x = omega.index_select(-1, self.cols) * self.inv_scale
        _, (h, _) = enc["lstm"](fn.elu(enc["embed"](x)))
        return h[0]

    def _map(self, enc: nn.ModuleDict, omega: torch.Tensor, cell: torch.Tensor, grid: tuple[int, int],
             weight: nn.Linear | None) -> torch.Tensor:
        """Agents (B, K, H, D) with cells (B, K) -> pooled map (B, C, gx, gy); only present agents are encoded."""
        b, k = cell.shape
        c = self.cfg.encoder
        flat = cell.reshape(-1)
        have = flat >= 0
        # Encode present slots only, their count rounded up to a multiple of 128: few distinct shapes, so
        # oneDNN reuses its LSTM kernels, and empty slots cost (almost) nothing.
        n = min(b * k, -(-int(have.sum()) // 128) * 128)
        rows = torch.argsort((~have).to(torch.int8), stable=True)[:n]
        hj = self._encode(enc, omega.reshape(b * k, *omega.shape[2:]).index_select(0, rows))
        if weight is not None:
            hj = fn.elu(weight(hj))
        h = torch.zeros(b * k, c, dtype=hj.dtype).index_copy(0, rows, hj) * have.unsqueeze(1).to(hj.dtype)
        g = grid[0] * grid[1]
        slot = (torch.arange(b).repeat_interleave(k) * (g + 1) + torch.where(flat >= 0, flat, g))
        pooled = torch.zeros(b * (g + 1), c, dtype=h.dtype).index_add(0, slot, h)  # sum of agents per cell
        return pooled.reshape(b, g + 1, c)[:, :g].reshape(b, grid[0], grid[1], c).permute(0, 3, 1, 2)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        cfg = self.cfg
        parts = [self._encode(self.ego, batch["hist"])]
        if cfg.horizon:
            hz_map = self._map(self.hz, batch["hz"], batch["hz_cell"], cfg.horizon_grid, self.hz_weight)
            parts.append(self.hz_conv(hz_map))
        nb_map = self._map(self.nbr, batch["nbr"], batch["nbr_cell"], cfg.neighbour_grid, None)
        parts.append(self.nbr_conv(nb_map))
        z = torch.cat(parts, -1)
        y, _ = self.decoder(z[:, None].expand(-1, cfg.future, -1))
        o = self.out(y)
        # Means as summed per-step displacements: a constant output is constant velocity, easy to start from.
        mu = torch.cumsum(o[..., :2], 1) * cfg.step_scale
        sigma = (fn.softplus(o[..., 2:4]) + 1e-3) * cfg.pos_scale
        return torch.cat([mu, sigma, torch.tanh(o[..., 4:5])], -1)
