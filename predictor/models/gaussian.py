"""The bivariate Gaussian output every learned model emits per future step, and the residual form of its means."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as fn

from predictor.features import FEATURES
from predictor.models.config import ModelConfig

_XY = [FEATURES.index("x"), FEATURES.index("y")]
_PRESENT = FEATURES.index("present")


def gaussian_head(o: torch.Tensor, scale: float, mu: torch.Tensor | None = None) -> torch.Tensor:
    """Raw outputs (..., 5) -> (mu_x, mu_y, sigma_x, sigma_y, rho) (..., 5): metres, sigma > 0, |rho| < 1.

    mu: optional (..., 2) means in metres computed by the model itself (TraPHic sums per-step
    displacements; residual models add a correction to constant velocity); by default o[..., :2] * scale.
    """
    mu = o[..., :2] * scale if mu is None else mu
    sigma = (fn.softplus(o[..., 2:4]) + 1e-3) * scale
    return torch.cat([mu, sigma, torch.tanh(o[..., 4:5])], -1)


def cv_step(hist: torch.Tensor) -> torch.Tensor:
    """The target's last displacement per window step (B, 2), metres, from its Omega hist (B, H, D).

    Now (the last step) minus the latest earlier step where the target is present, divided by the steps
    between them (one step back when present: the constant-velocity baseline's lag 1); zero without one.
    """
    xy, present = hist[..., _XY], hist[..., _PRESENT] > 0.5
    h = hist.shape[1]
    ks = torch.arange(h - 1, device=hist.device)
    prev = torch.where(present[:, :-1], ks, -1).amax(1)  # (B,) latest earlier present step, -1 none
    gap = (h - 1 - prev).clamp_min(1).to(hist.dtype)
    back = xy.gather(1, prev.clamp_min(0)[:, None, None].expand(-1, 1, 2))[:, 0]
    step = (xy[:, -1] - back) / gap[:, None]
    return torch.where((prev >= 0)[:, None], step, torch.zeros_like(step))


def lag_steps(hist: torch.Tensor, lags: int) -> torch.Tensor:
    """Mean displacement per window step over the last 2 .. lags steps (B, lags - 1, 2), metres, target frame:
    (now - the position l steps back) / l; `cv_step` where the target was absent l steps back."""
    xy, present = hist[..., _XY], hist[..., _PRESENT] > 0.5
    ls = torch.arange(2, lags + 1, device=hist.device)
    back = xy[:, -1 - ls]  # (B, L - 1, 2)
    d = (xy[:, -1, None] - back) / ls[None, :, None].to(hist.dtype)
    return torch.where(present[:, -1 - ls, None], d, cv_step(hist)[:, None])


class LagBlend(nn.Module):
    """A residual model whose constant velocity is the last displacement plus a learned blend of longer lags:
    means + k * sum_l w_l (lag_steps_l - cv_step) at future step k. w starts at zero (exactly the model it wraps)
    and is learned with the rest; `cfg`, `name` and the Gaussian of the wrapped model are kept. With cfg.cv_gate
    each track's w_l is w_l + g_l * jitter(track) (`track_jitter`, g zero at the start too): one model smooths the
    tracks whose noise is in the annotation and keeps, or extrapolates the trend of, the clean ones. With
    cfg.cv_gate_pool the gate reads the jitter pooled over the target and the agents around it (`pooled_jitter`)."""

    RATE = 10.0  # w is stored divided by this, so Adam's steps move it as fast as the network's outputs

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net, self.cfg = net, net.cfg
        self.w = nn.Parameter(torch.zeros(net.cfg.cv_lags - 1))
        self.g = nn.Parameter(torch.zeros(net.cfg.cv_lags - 1)) if getattr(net.cfg, "cv_gate", False) else None

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        out, hist = self.net(batch), batch["hist"]
        if self.g is None:
            w = self.w[None]
        else:
            jitter = pooled_jitter(batch) if self.cfg.cv_gate_pool else track_jitter(hist)
            w = self.w[None] + jitter[:, None] * self.g[None]
        delta = ((lag_steps(hist, self.cfg.cv_lags) - cv_step(hist)[:, None]) * (w * self.RATE)[..., None]).sum(1)
        k = torch.arange(1, out.shape[1] + 1, device=out.device, dtype=out.dtype)
        return torch.cat([out[..., :2] + k[None, :, None] * delta[:, None], out[..., 2:]], -1)


def _bend_sums(tracks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The lag-1 products and the squares of the second differences of tracks (..., H, D) over their present
    steps, each summed over steps and axes -> two (...) tensors."""
    xy, present = tracks[..., _XY], tracks[..., _PRESENT] > 0.5
    d2 = xy[..., 2:, :] - 2 * xy[..., 1:-1, :] + xy[..., :-2, :]  # (..., H - 2, 2)
    ok = (present[..., 2:] & present[..., 1:-1] & present[..., :-2]).to(tracks.dtype)
    d2 = d2 * ok[..., None]
    return (d2[..., 1:, :] * d2[..., :-1, :]).sum((-2, -1)), (d2 * d2).sum((-2, -1))


def track_jitter(hist: torch.Tensor) -> torch.Tensor:
    """How much of a track's observed motion is annotation noise (B,), in [-1, 1]: minus the lag-1
    autocorrelation of its second differences over the present steps of hist (B, H, D). White position noise
    gives up to 2/3 (each noisy point bends the track one way, then back; about 0.5 over 8 steps), a smooth
    path's steady turns and speed changes about -1 (-5/6 over 8 steps); 0 without three present pairs."""
    lag1, sq = _bend_sums(hist)
    return -lag1 / (sq + 1e-6)


def pooled_jitter(batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """`track_jitter` of the target and the agents in its neighbour and horizon slots together (B,): annotation
    noise is the recording's, so the agents around a target estimate it better than its one short track."""
    lag1, sq = _bend_sums(torch.cat([batch["hist"][:, None], batch["nbr"], batch["hz"]], 1))  # (B, 1 + K)
    return -lag1.sum(1) / (sq.sum(1) + 1e-6)


def cv_extrapolation(hist: torch.Tensor, future: int) -> torch.Tensor:
    """Constant-velocity means (B, F, 2), metres, target frame: now + k * cv_step for k = 1 .. F."""
    k = torch.arange(1, future + 1, device=hist.device, dtype=hist.dtype)
    return hist[:, -1, None, _XY] + k[None, :, None] * cv_step(hist)[:, None]


def residual_means(o_mu: torch.Tensor, hist: torch.Tensor, scale: float) -> torch.Tensor:
    """Constant velocity plus a correction that grows along the horizon: o_mu (B, F, 2) raw corrections, scaled by
    `scale` metres per unit at the last step and by (k / F)^2 at step k, as a constant acceleration departs from
    constant velocity (the first steps stay near it; each step's correction is its own output, not a sum over
    earlier ones) -> means (B, F, 2) metres."""
    f = o_mu.shape[1]
    ramp = (torch.arange(1, f + 1, device=o_mu.device, dtype=o_mu.dtype)[:, None] / f) ** 2 * scale
    return cv_extrapolation(hist, f) + o_mu * ramp


def zero_means(layer: nn.Linear, rows: int = 2) -> None:
    """Zero the first `rows` outputs of `layer` (the mean corrections): a residual model starts as constant
    velocity exactly."""
    with torch.no_grad():
        layer.weight[:rows].zero_()
        layer.bias[:rows].zero_()


def output(o: torch.Tensor, cfg: ModelConfig, hist: torch.Tensor, mu: torch.Tensor | None = None) -> torch.Tensor:
    """A model's raw outputs (B, F, 5) -> its Gaussian (B, F, 5): the residual form when cfg.residual, else
    the model's own means `mu` (default o[..., :2] * pos_scale); hist (B, H, D) the target's Omega."""
    if cfg.residual:
        mu = residual_means(o[..., :2], hist, cfg.residual_scale)
    return gaussian_head(o, cfg.pos_scale, mu)
