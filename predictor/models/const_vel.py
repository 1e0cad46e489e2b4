"""Constant velocity: the baseline every learned predictor must beat."""

from __future__ import annotations

import numpy as np

from simharness.scene import Forecast, Scene, heading_velocity


class ConstantVelocity:
    """Extrapolates each target's velocity over the last `lag` frames of its history.

    Where the frame `lag` back is missing, the scene's speed along its heading at now is used.
    """

    name = "const-vel"

    def __init__(self, lag: int = 1):
        self.lag = int(lag)
        if self.lag != 1:  # reports and tables tell the smoothed reference from the plain one
            self.name = f"const-vel:{self.lag}"

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        """history (N agents, T frames), targets (M,) rows present at the last frame -> Forecast (M, horizon, 2)."""
        targets = np.asarray(targets, np.int64)
        now = history.num_frames - 1
        lag = min(self.lag, now)
        xy = history.xy[targets, now].astype(np.float64)
        if lag > 0:
            prev_ok = history.valid[targets, now - lag]
            vel = (xy - history.xy[targets, now - lag]) / (lag * history.dt)
        else:
            prev_ok = np.zeros(len(targets), bool)
            vel = np.zeros_like(xy)
        h, v = history.heading[targets, now], history.speed[targets, now]
        fallback = heading_velocity(v, h)
        vel = np.where(prev_ok[:, None], vel, fallback)
        t = np.arange(1, horizon + 1) * history.dt
        mean = xy[:, None] + vel[:, None] * t[None, :, None]
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=history.dt)
