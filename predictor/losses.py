"""Training losses on model outputs in the target's frame (metres).

pred (B, F, 5) = (mu_x, mu_y, sigma_x, sigma_y, rho): sigma are standard deviations (> 0, the model
makes them positive with softplus), rho a correlation in (-1, 1) (tanh). fut (B, F, 2), mask (B, F).
"""

from __future__ import annotations

import math

import torch

_LOG_2PI = math.log(2 * math.pi)


def gaussian_nll(pred: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean negative log-likelihood (nats per valid point) of a bivariate Gaussian.

    -log p = log 2pi + log sx + log sy + 0.5 log(1 - rho^2) + z / (2 (1 - rho^2)),
    z = dx^2/sx^2 + dy^2/sy^2 - 2 rho dx dy / (sx sy).
    """
    dx, dy = fut[..., 0] - pred[..., 0], fut[..., 1] - pred[..., 1]
    sx, sy = pred[..., 2], pred[..., 3]
    rho = pred[..., 4].clamp(-0.9999, 0.9999)
    one_r2 = 1 - rho**2
    z = (dx / sx) ** 2 + (dy / sy) ** 2 - 2 * rho * dx * dy / (sx * sy)
    nll = _LOG_2PI + torch.log(sx) + torch.log(sy) + 0.5 * torch.log(one_r2) + z / (2 * one_r2)
    m = mask.to(nll.dtype)
    return (nll * m).sum() / m.sum().clamp_min(1)


def mse(pred: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared Euclidean error (m^2 per valid point) of the predicted means."""
    sq = ((pred[..., :2] - fut) ** 2).sum(-1)
    m = mask.to(sq.dtype)
    return (sq * m).sum() / m.sum().clamp_min(1)


def ade(pred: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean Euclidean error (m per valid point) of the predicted means: the ADE itself, robust to the few huge
    misses of real tracks (an identity switch, a box that jumps) that dominate a squared error."""
    d = torch.sqrt(((pred[..., :2] - fut) ** 2).sum(-1) + 1e-6)  # the epsilon keeps the gradient finite at 0
    m = mask.to(d.dtype)
    return (d * m).sum() / m.sum().clamp_min(1)


def correction(pred: torch.Tensor, hist: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean Euclidean distance (m per valid point) of the predicted means from constant-velocity extrapolation of the
    target's Omega history hist (B, H, D): how far a residual model's correction moves its forecast."""
    from predictor.models.gaussian import cv_extrapolation

    return ade(pred, cv_extrapolation(hist, pred.shape[1]), mask)


def nll_mse(pred: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The means fit by MSE alone, sigma and rho by the NLL around the means held fixed: NLL (means detached) +
    MSE. The joint NLL lets a model widen sigma where its means are poor instead of improving them."""
    return gaussian_nll(torch.cat([pred[..., :2].detach(), pred[..., 2:]], -1), fut, mask) + mse(pred, fut, mask)


def loss_for_epoch(epoch: int, warmup_epochs: int) -> str:
    """"mse" for the first `warmup_epochs` epochs (means first), then "nll"."""
    return "mse" if epoch < warmup_epochs else "nll"


def nll_ade(pred: torch.Tensor, fut: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """As `nll_mse`, with the means fit by the mean Euclidean error (`ade`)."""
    return gaussian_nll(torch.cat([pred[..., :2].detach(), pred[..., 2:]], -1), fut, mask) + ade(pred, fut, mask)


def loss_name(kind: str, mean_loss: str) -> str:
    """The LOSSES key for an epoch of `kind` ("mse" warm-up or "nll") when the means are fit by `mean_loss`
    ("nll": the paper's joint NLL; "mse"; "ade")."""
    if kind == "mse":
        return "ade" if mean_loss == "ade" else "mse"
    return {"nll": "nll", "mse": "nll+mse", "ade": "nll+ade"}[mean_loss]


LOSSES = {"mse": mse, "ade": ade, "nll": gaussian_nll, "nll+mse": nll_mse, "nll+ade": nll_ade}
