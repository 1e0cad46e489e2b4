"""CS-LSTM (Deo and Trivedi, CVPR-W 2018): convolutional social pooling, in the lane-free form TraPHic used.

An LSTM encodes every agent's positions (target and neighbours, shared weights). The neighbours'
encodings are placed on the neighbour grid (predictor.features: cells over the neighbourhood in the
target's frame, summed where agents share a cell), then a 3x3 convolution, a 3x1 convolution along
the direction of travel and a 2x1 max-pool give the social context; the target's own encoding goes
through a fully connected layer. Both feed an LSTM decoder with a bivariate Gaussian output.

Lane-free, as in the paper's comparison: no lane grid and no manoeuvre classes or manoeuvre-conditioned
decoders (the original needs lane ids); the grid is the same lane-less grid TraPHic's neighbour map uses.
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
class CSLSTMConfig(ModelConfig):
    """Sizes as in the original (embedding 32, encoder 64, decoder 128, convolutions 64 and 16 channels)."""

    dyn_embed: int = 32
    conv1: int = 64
    conv2: int = 16


class CSLSTM(nn.Module):
    """forward(batch) -> (B, F, 5) from batch["hist"], batch["nbr"] (B, K, H, D) and batch["nbr_cell"] (B, K)."""

    name = "cs-lstm"

    def __init__(self, cfg: CSLSTMConfig):
        super().__init__()
        gx, gy = cfg.neighbour_grid
        if gx < 5 or gy < 3:
            raise ValueError(f"CS-LSTM needs a neighbour grid of at least 5 x 3 cells, got {gx} x {gy}")
        self.cfg = cfg
        self.embed = nn.Linear(2, cfg.embed)
        self.encoder = nn.LSTM(cfg.embed, cfg.encoder, batch_first=True)
        self.dyn = nn.Linear(cfg.encoder, cfg.dyn_embed)
        self.conv = nn.Sequential(nn.Conv2d(cfg.encoder, cfg.conv1, 3), nn.LeakyReLU(0.1),
                                  nn.Conv2d(cfg.conv1, cfg.conv2, (3, 1)), nn.LeakyReLU(0.1),
                                  nn.MaxPool2d((2, 1), padding=(1, 0)), nn.Flatten())
        social = cfg.conv2 * ((gx - 4) // 2 + 1) * (gy - 2)
        self.decoder = nn.LSTM(cfg.dyn_embed + social, cfg.decoder, batch_first=True)
        self.out = nn.Linear(cfg.decoder, 5)
        if cfg.residual:
            zero_means(self.out)

    def _encode(self, omega: torch.Tensor) -> torch.Tensor:
        """omega (M, H, D) -> (M, encoder)."""
        xy, present = positions(omega, self.cfg.pos_scale)
        _, (h, _) = self.encoder(fn.leaky_relu(self.embed(xy), 0.1) * present[..., None])
        return h[0]

    def social_tensor(self, nbr: torch.Tensor, cell: torch.Tensor) -> torch.Tensor:
        """Neighbours (B, K, H, D) in cells (B, K) (-1 none) -> (B, encoder, gx, gy) grid of their encodings."""
        b, k = cell.shape
        gx, gy = self.cfg.neighbour_grid
        g = gx * gy
        flat = cell.reshape(-1)
        have = torch.nonzero(flat >= 0).squeeze(1)
        h = nbr.new_zeros(b * k, self.cfg.encoder)
        if have.numel():  # only real neighbours are encoded
            h = h.index_copy(0, have, self._encode(nbr.reshape(b * k, *nbr.shape[2:]).index_select(0, have)))
        slot = torch.arange(b, device=flat.device).repeat_interleave(k) * (g + 1) + torch.where(flat >= 0, flat, g)
        pooled = h.new_zeros(b * (g + 1), h.shape[1]).index_add(0, slot, h)  # row g of each sample: "no cell"
        return pooled.view(b, g + 1, -1)[:, :g].reshape(b, gx, gy, -1).permute(0, 3, 1, 2)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        ego = fn.leaky_relu(self.dyn(self._encode(batch["hist"])), 0.1)
        soc = self.conv(self.social_tensor(batch["nbr"], batch["nbr_cell"]))
        z = torch.cat([soc, ego], -1)
        y, _ = self.decoder(z[:, None].expand(-1, self.cfg.future, -1))
        return output(self.out(y), self.cfg, batch["hist"])
