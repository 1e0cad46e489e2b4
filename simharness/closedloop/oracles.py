"""Reference forecasters of the closed loop: the oracle (the others' true future) and "static".

The oracle (`predictor="oracle"`) gets the others' true future, by one of two means:
- backends that can be cloned (highway: the whole simulator deep-copies, RNG included) get a
  look-ahead: at each prediction step a copy of the live simulator is stepped `horizon` frames with
  the ego on the simulator's own model, and the others' positions in it are the forecast. Exact
  whenever the background does not react to the ego (`reaction = "ignore"`); otherwise exact up to
  how the others react to the ego's actual, rather than the model's, driving over those seconds.
- others (SUMO: libsumo cannot be copied in-process) get a replay: a reference rollout of the same
  seed with the ego on the simulator's own model is recorded first; an agent's forecast is its
  reference future, shifted to start where the agent really is, if the reference had it within 1 m
  of its real position now, and constant velocity otherwise. Exact with `reaction = "ignore"` (the
  background then never depends on the ego); with a reacting background the traffic of the two
  runs drifts apart, and the oracle falls back to constant velocity for the agents that drifted.
Its online error is reported like any predictor's, so how exact it was is visible in every scorecard.
"""

from __future__ import annotations

import copy

import numpy as np

from simharness.planners import rows_of
from simharness.scene import Forecast, Scene

# ---------------------------------------------------------------------- the oracle
CLONABLE_BACKENDS = ("highway",)  # simulators that copy.deepcopy exactly (state and RNG)


def _constant_velocity(history: Scene, targets: np.ndarray, horizon: int) -> np.ndarray:
    """(M, horizon, 2) constant-velocity extrapolation of history rows `targets` from their last step."""
    vel = history.velocity[targets, -1]
    steps = (np.arange(horizon) + 1)[None, :, None] * history.dt
    return (history.xy[targets, -1][:, None] + vel[:, None] * steps).astype(np.float32)


class StaticForecast:
    """"static": the sampling planner with no prediction at all: everyone stays where they are now."""

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        targets = np.asarray(targets, int)
        mean = np.repeat(history.xy[targets, -1][:, None], horizon, axis=1)
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=history.dt)


class ReplayOracle:
    """True futures from a reference recording of the same seed (see the module docstring).

    reference: the recorded Scene; `history.frame0 + history.num_frames - 1` is "now" in its frames.
    tolerance: m; agents the reference placed farther than this from where they are now fall back
    to constant velocity.
    """

    def __init__(self, reference: Scene, tolerance: float = 1.0) -> None:
        self.reference = reference
        self.tolerance = tolerance

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        """Forecast (M, horizon, 2) of history rows `targets`."""
        targets = np.asarray(targets, int)
        now = history.frame0 + history.num_frames - 1
        ref = self.reference
        rows = rows_of(ref.agent_id, history.agent_id[targets])
        cols = np.minimum(now + np.arange(horizon + 1), ref.num_frames - 1)  # now, then the future
        inside = (now + np.arange(horizon + 1)) < ref.num_frames
        r = np.maximum(rows, 0)
        path = ref.xy[r][:, cols]  # (M, horizon + 1, 2)
        ok = (rows >= 0)[:, None] & inside[None] & ref.valid[r][:, cols]
        offset = history.xy[targets, -1] - path[:, 0]
        agree = ok[:, 0] & (np.linalg.norm(offset, axis=-1) <= self.tolerance)
        mean = np.where((ok[:, 1:] & agree[:, None])[..., None], path[:, 1:] + offset[:, None],
                        _constant_velocity(history, targets, horizon))
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=history.dt)


class LookaheadOracle:
    """True futures from a copy of the live simulator stepped ahead (see the module docstring)."""

    def __init__(self) -> None:
        self.sim = None  # set by `simulate` once the simulator exists

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        """Forecast (M, horizon, 2) of history rows `targets`; constant velocity for agents that leave."""
        targets = np.asarray(targets, int)
        clone = copy.deepcopy(self.sim)
        ids = history.agent_id[targets]
        mean = _constant_velocity(history, targets, horizon)
        for f in range(horizon):  # frames of the copy; agents matched by id inside, vectorised
            frame = clone.step(None)
            hit = rows_of(frame.agent_id, ids)
            mean[hit >= 0, f] = frame.xy[hit[hit >= 0]]
        return Forecast(agent_id=ids, mean=mean, dt=history.dt)

