"""Displacement metrics of forecasts against ground truth: pure functions of arrays and masks.

Shapes: M forecast samples (target agents x windows), F future frames, K sampled futures.
Every function takes a `valid` mask (M, F) beside the arrays; invalid entries are ignored.
Two conventions are reported, always labelled:
- mean Euclidean ADE/FDE (the field's usual meaning): mean of per-point distances;
- RMSE ADE/FDE (the TraPHic paper's tables): square root of the mean squared distance.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np


def point_errors(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean distance per point: pred, truth (M, F, 2) -> (M, F) metres."""
    return np.linalg.norm(np.asarray(pred, np.float64) - np.asarray(truth, np.float64), axis=-1)


def _mean(x: np.ndarray, w: np.ndarray) -> float:
    n = float(w.sum())
    return float((x * w).sum() / n) if n else math.nan


def ade(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> float:
    """Mean Euclidean error over all valid points: (M, F, 2), (M, F, 2), (M, F) -> metres."""
    return _mean(point_errors(pred, truth), np.asarray(valid, bool))


def _last_valid(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, F) -> (rows with any valid point, their last valid column)."""
    valid = np.asarray(valid, bool)
    has = valid.any(axis=1)
    last = valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1)
    return np.flatnonzero(has), last[has]


def fde(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> float:
    """Mean Euclidean error at each sample's last valid future frame: (M, F, 2) x2, (M, F) -> metres."""
    rows, cols = _last_valid(valid)
    if rows.size == 0:
        return math.nan
    return float(point_errors(pred, truth)[rows, cols].mean())


def ade_rmse(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> float:
    """RMSE over all valid points (the paper's ADE): (M, F, 2) x2, (M, F) -> metres."""
    return math.sqrt(_mean(point_errors(pred, truth) ** 2, np.asarray(valid, bool)))


def fde_rmse(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> float:
    """RMSE at each sample's last valid future frame (the paper's FDE) -> metres."""
    rows, cols = _last_valid(valid)
    if rows.size == 0:
        return math.nan
    return math.sqrt(float((point_errors(pred, truth)[rows, cols] ** 2).mean()))


def rmse_per_step(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """RMSE at each future frame over samples: (M, F, 2) x2, (M, F) -> (F,) metres (nan where no sample)."""
    valid = np.asarray(valid, bool)
    sq = np.where(valid, point_errors(pred, truth) ** 2, 0.0).sum(0)
    n = valid.sum(0)
    return np.sqrt(np.divide(sq, n, out=np.full(sq.shape, np.nan), where=n > 0))


def rmse_per_second(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray, dt: float) -> np.ndarray:
    """RMSE at each whole horizon second (the paper's Figure 5).

    (M, F, 2) x2, (M, F), dt seconds per frame -> (S,) metres for t = 1 s .. S s, S = floor(F dt).
    """
    per_step = rmse_per_step(pred, truth, valid)
    seconds = np.arange(1, int(math.floor(per_step.size * dt + 1e-9)) + 1)
    cols = np.round(seconds / dt).astype(int) - 1  # frame k is at time (k + 1) dt
    return per_step[cols]


def miss_rate(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray, threshold: float = 2.0) -> float:
    """Share of samples whose final-point error exceeds `threshold` metres: (M, F, 2) x2, (M, F) -> [0, 1]."""
    rows, cols = _last_valid(valid)
    if rows.size == 0:
        return math.nan
    return float((point_errors(pred, truth)[rows, cols] > threshold).mean())


def bivariate_nll(mean: np.ndarray, sigma_rho: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> float:
    """Mean negative log-likelihood per valid point of a bivariate Gaussian, in nats.

    mean (M, F, 2), sigma_rho (M, F, 3) = (sigma_x, sigma_y standard deviations > 0, rho in (-1, 1)),
    truth (M, F, 2), valid (M, F).
    -log p = log(2 pi) + log sx + log sy + 0.5 log(1 - rho^2) + z / (2 (1 - rho^2)),
    z = dx^2/sx^2 + dy^2/sy^2 - 2 rho dx dy / (sx sy).
    """
    d = np.asarray(truth, np.float64) - np.asarray(mean, np.float64)
    sr = np.asarray(sigma_rho, np.float64)
    sx, sy, rho = sr[..., 0], sr[..., 1], np.clip(sr[..., 2], -0.999999, 0.999999)
    one_r2 = 1.0 - rho**2
    z = (d[..., 0] / sx) ** 2 + (d[..., 1] / sy) ** 2 - 2 * rho * d[..., 0] * d[..., 1] / (sx * sy)
    nll = math.log(2 * math.pi) + np.log(sx) + np.log(sy) + 0.5 * np.log(one_r2) + z / (2 * one_r2)
    valid = np.asarray(valid, bool)
    return _mean(np.where(valid, nll, 0.0), valid)


def min_ade_fde(modes: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """Best-of-K mean Euclidean ADE and FDE for sampled forecasts.

    modes (M, K, F, 2), truth (M, F, 2), valid (M, F) -> (minADE, minFDE) metres; the minimum over
    the K samples is taken per target (ADE and FDE minimised separately, as in Social-GAN).
    """
    valid = np.asarray(valid, bool)
    err = point_errors(modes, np.asarray(truth)[:, None])  # (M, K, F)
    n = valid.sum(1)
    has = n > 0
    per_ade = np.where(valid[:, None], err, 0.0).sum(-1)[has] / n[has, None]
    rows, cols = _last_valid(valid)
    per_fde = err[rows, :, cols]  # (M', K)
    if not has.any():
        return math.nan, math.nan
    return float(per_ade.min(1).mean()), float(per_fde.min(1).mean())


def summary(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> dict[str, float | int]:
    """ADE/FDE both ways and the sample count: (M, F, 2) x2, (M, F) -> dict."""
    return {
        "ade": ade(pred, truth, valid), "fde": fde(pred, truth, valid),
        "ade_rmse": ade_rmse(pred, truth, valid), "fde_rmse": fde_rmse(pred, truth, valid),
        "samples": int(np.asarray(valid, bool).any(1).sum()),
    }


def by_group(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray, groups: np.ndarray,
             names: Mapping[int, str] | None = None) -> dict[str, dict[str, float | int]]:
    """`summary` per group: groups (M,) int labels (agent type, density bin) -> {name: summary}."""
    groups = np.asarray(groups)
    out = {}
    for g in np.unique(groups):  # a handful of groups, each metric vectorised inside
        rows = groups == g
        key = names[int(g)] if names is not None else str(g)
        out[key] = summary(pred[rows], truth[rows], valid[rows])
    return out


def density_bins(counts: np.ndarray, edges: tuple[int, ...] = (5, 10, 20)) -> tuple[np.ndarray, dict[int, str]]:
    """Local agent counts (M,) -> bin index (M,) and bin names, e.g. '<5', '5-9', '10-19', '>=20'."""
    counts = np.asarray(counts)
    idx = np.searchsorted(np.asarray(edges), counts, side="right")
    names = {0: f"<{edges[0]}"}
    for i in range(1, len(edges)):
        names[i] = f"{edges[i - 1]}-{edges[i] - 1}"
    names[len(edges)] = f">={edges[-1]}"
    return idx, names
