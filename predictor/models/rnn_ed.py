"""RNN-ED (Seq2Seq): an LSTM encoder-decoder on the target's own history, the paper's first baseline.

The target's positions (x, y) in its own frame are embedded, encoded by an LSTM, and the last hidden
state, repeated over the horizon, drives an LSTM decoder that emits a bivariate Gaussian per future
step. No neighbours: it measures how far a model gets without interactions.

Also here, because every baseline shares it: `positions` (the position inputs of any Omega tensor).
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn
from torch.nn import functional as fn

from predictor.features import FEATURES
from predictor.models.config import ModelConfig
from predictor.models.gaussian import output, zero_means

_XY = [FEATURES.index("x"), FEATURES.index("y")]
_PRESENT = FEATURES.index("present")


def positions(omega: torch.Tensor, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Omega (..., H, D) -> (positions (..., H, 2) divided by `scale`, present (..., H) bool)."""
    return omega[..., _XY] / scale, omega[..., _PRESENT] > 0.5


@dataclasses.dataclass(frozen=True)
class RNNEDConfig(ModelConfig):
    """Sizes; the window fields (history ... horizon_grid) are filled in by training and unused here."""


class RNNED(nn.Module):
    """forward(batch) -> (B, F, 5) from batch["hist"] (B, H, D) only."""

    name = "rnn-ed"

    def __init__(self, cfg: RNNEDConfig):
        super().__init__()
        self.cfg = cfg
        self.embed = nn.Linear(2, cfg.embed)
        self.encoder = nn.LSTM(cfg.embed, cfg.encoder, batch_first=True)
        self.decoder = nn.LSTM(cfg.encoder, cfg.decoder, batch_first=True)
        self.out = nn.Linear(cfg.decoder, 5)
        if cfg.residual:
            zero_means(self.out)

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        xy, present = positions(batch["hist"], self.cfg.pos_scale)
        x = fn.leaky_relu(self.embed(xy), 0.1) * present[..., None]  # missing steps carry no input
        _, (h, _) = self.encoder(x)
        y, _ = self.decoder(h[0][:, None].expand(-1, self.cfg.future, -1))
        return output(self.out(y), self.cfg, batch["hist"])
