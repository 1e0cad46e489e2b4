"""The bivariate Gaussian output every learned model emits per future step."""

from __future__ import annotations

import torch
from torch.nn import functional as fn


def gaussian_head(o: torch.Tensor, scale: float, mu: torch.Tensor | None = None) -> torch.Tensor:
    """Raw outputs (..., 5) -> (mu_x, mu_y, sigma_x, sigma_y, rho) (..., 5): metres, sigma > 0, |rho| < 1.

    mu: optional (..., 2) means in metres computed by the model itself (TraPHic sums per-step
    displacements); by default o[..., :2] * scale.
    """
    mu = o[..., :2] * scale if mu is None else mu
    sigma = (fn.softplus(o[..., 2:4]) + 1e-3) * scale
    return torch.cat([mu, sigma, torch.tanh(o[..., 4:5])], -1)
