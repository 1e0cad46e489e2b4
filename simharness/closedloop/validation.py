"""What the loop accepts from a predictor: a forecast checked before the planner sees it, and its coverage.

A forecast that the planner cannot use (not a `Forecast`, positions or sigmas NaN or infinite, a shape other
than mean (M, F, 2) with F >= the requested horizon, agent ids that are not among the targets it was asked
about, or the same id twice) stops the run with one line naming the predictor (`UserError`, exit 2): a
planner fed NaN would drive on nothing and the scores would look like a good predictor's.

A forecast may leave targets out (M <= the number asked about); the share it answered is its coverage.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.scene import Forecast


def validate_forecast(forecast: Any, predictor: str, targets: np.ndarray, horizon: int) -> Forecast:
    """The forecast itself when the planner can use it; UserError naming `predictor` and the fault otherwise.

    forecast: what `predict` returned; targets (T,) str: ids of the agents it was asked about;
    horizon: frames requested. Returns the forecast unchanged (mean (M, F, 2), M <= T, F >= horizon).
    """
    where = f"predictor {predictor!r}"
    if not isinstance(forecast, Forecast):
        raise UserError(f"{where} returned {type(forecast).__name__}; expected a simharness.scene.Forecast")
    mean = np.asarray(forecast.mean)
    ids = np.asarray(forecast.agent_id)
    if mean.ndim != 3 or mean.shape[0] != ids.shape[0] or mean.shape[2] != 2:
        raise UserError(f"{where}: forecast mean has shape {mean.shape}; expected ({ids.shape[0]}, F, 2), one row "
                        "per agent id")
    if mean.shape[1] < horizon:
        raise UserError(f"{where}: forecast covers {mean.shape[1]} frames; {horizon} were asked for")
    if not np.isfinite(mean).all():
        bad = ids[~np.isfinite(mean).all(axis=(1, 2))]
        raise UserError(f"{where}: forecast mean is NaN or infinite for {bad.size} of {ids.size} agents "
                        f"(first {bad[0]!s})")
    if forecast.sigma_rho is not None and not np.isfinite(forecast.sigma_rho).all():
        raise UserError(f"{where}: forecast sigma_rho (sigma_x, sigma_y, rho) is NaN or infinite")
    stray = ~np.isin(ids, targets)
    if stray.any():
        raise UserError(f"{where}: forecast names agent {ids[stray][0]!s}, which is not among the "
                        f"{len(targets)} agents it was asked about")
    if np.unique(ids).size != ids.size:
        raise UserError(f"{where}: forecast names the same agent twice")
    return forecast


def answered(forecast: Forecast | None, targets: np.ndarray) -> int:
    """How many of the targets (T,) ids the forecast forecasts (0 when there is none)."""
    if forecast is None or len(targets) == 0:
        return 0
    return int(np.isin(targets, np.asarray(forecast.agent_id)).sum())
