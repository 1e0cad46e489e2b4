"""A predictor plug-in: constant acceleration along each target's direction of motion, stopping at rest.

    simharness evaluate --data DATA --model examples/const_accel.py:ConstAccel --split all
    simharness closedloop stress/cut_in --predictor examples/const_accel.py:ConstAccel --seeds 0-9
"""

from __future__ import annotations

import numpy as np

from simharness.scene import Forecast, Scene


class ConstAccel:
    """Extrapolates each target's speed change over its last two steps (m/s^2, clipped to +-max_accel) along
    its current direction of motion; a decelerating target stops and stays put rather than reversing."""

    name = "const-accel"

    def __init__(self, max_accel: float = 3.0) -> None:
        self.max_accel = max_accel

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        """history: N agents x T frames (column -1 is now), world frame, metres; targets: (M,) rows present
        now; horizon: F future frames of history.dt seconds -> Forecast with mean (M, F, 2) metres."""
        targets = np.asarray(targets, np.int64)
        dt = history.dt
        xy = history.xy[targets, -3:].astype(np.float64)  # (M, 3, 2): two steps back, one back, now
        ok = history.valid[targets, -3:]
        if xy.shape[1] < 3:  # fewer than three frames of history: no acceleration to measure
            xy, ok = np.repeat(xy[:, -1:], 3, 1), np.zeros((len(targets), 3), bool)
        v_now = (xy[:, 2] - xy[:, 1]) / dt  # (M, 2) m/s
        v_prev = (xy[:, 1] - xy[:, 0]) / dt
        heading, speed = history.heading[targets, -1], history.speed[targets, -1]
        v_now = np.where(ok[:, 1:].all(1)[:, None], v_now,
                         np.stack([np.cos(heading), np.sin(heading)], -1) * speed[:, None])
        s0 = np.linalg.norm(v_now, axis=-1)  # (M,) speed, m/s
        direction = v_now / np.maximum(s0, 1e-6)[:, None]
        accel = np.where(ok.all(1), (s0 - np.linalg.norm(v_prev, axis=-1)) / dt, 0.0)
        accel = np.clip(accel, -self.max_accel, self.max_accel)  # (M,) m/s^2 along the motion
        t = np.arange(1, horizon + 1) * dt  # (F,) seconds ahead
        stop = np.where(accel < 0, s0 / np.maximum(-accel, 1e-9), np.inf)  # (M,) seconds until at rest
        tt = np.minimum(t[None], stop[:, None])  # (M, F): time moving
        along = s0[:, None] * tt + 0.5 * accel[:, None] * tt**2  # (M, F) metres travelled
        mean = xy[:, 2, None] + along[..., None] * direction[:, None]
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=dt)
