"""What one closed-loop episode is given (`LoopConfig`, `EpisodeJob`), its clock (`LoopClock`) and record (`Issued`)."""

from __future__ import annotations

import dataclasses

from simharness.closedloop.perturbations import Perturbation
from simharness.pdm_planner import PDMConfig
from simharness.scenario import ScenarioSpec
from simharness.scene import Forecast


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """How the loop feeds the predictor and scores the episode."""

    history_s: float = 3.0  # seconds of history given to the predictor
    horizon_s: float = 5.0  # seconds forecast
    predict_hz: float = 2.5  # predictor calls per second; the planner replans every frame
    radius: float = PDMConfig.radius  # m: agents this close to the ego are given to the predictor (the planner's view)
    ttc_threshold: float = 1.5  # s: near miss below this time-to-collision
    ttc_horizon: float = 5.0  # s: time-to-collision extrapolation horizon
    stuck_speed: float = 0.5  # m/s: the ego counts as stuck below this speed
    oracle_window_s: float = 20.0  # s: how far each branch of the exact oracle is rolled ahead


@dataclasses.dataclass(frozen=True)
class EpisodeJob:
    """One closed-loop episode: picklable, so any executor can ship it to a worker."""

    spec: ScenarioSpec
    seed: int
    predictor: str  # traphic | const-vel | a run folder | oracle | static | none | blind
    config: LoopConfig = LoopConfig()
    keep_forecasts: bool = False  # return every forecast (for animations)
    keep_scene: bool = True
    perturbation: Perturbation | None = None  # degrade the predictor's forecasts (closedloop.perturbations)
    planner: str = "pdm"  # pdm | sampling | ppo | a policy .zip | file.py:NAME | module:NAME (episode.make_planner)


@dataclasses.dataclass
class Issued:
    """Forecasts issued during an episode (for online error and animations)."""

    frames: list[int] = dataclasses.field(default_factory=list)
    forecasts: list[Forecast] = dataclasses.field(default_factory=list)
    asked: int = 0  # agents in range summed over prediction steps (the targets the predictor was asked about)
    answered: int = 0  # of those, the ones that got a forecast (coverage = answered / asked)


class LoopClock:
    """When the loop predicts and which forecast the planner sees: the one piece of loop logic that the
    episode and the oracle's branches share, so that a branch drives its ego exactly as the episode would.

    every: frames between predictions. The planner acts once the ego has 2 frames of history; a forecast
    is due when none is held or `every` frames have passed; the planner sees the latest forecast shifted
    by the frames elapsed since it was made.
    """

    def __init__(self, every: int) -> None:
        self.every = every
        self.ego_frames = 0
        self.latest: Forecast | None = None
        self.latest_at = -1

    def tick(self, ego_present: bool) -> bool:
        """Count the ego's frames; whether the planner acts this frame."""
        self.ego_frames = self.ego_frames + 1 if ego_present else 0
        return self.ego_frames >= 2

    def due(self, k: int) -> bool:
        """Whether a forecast is due at frame k."""
        return self.latest is None or k - self.latest_at >= self.every

    def issue(self, k: int, forecast: Forecast | None) -> None:
        self.latest, self.latest_at = forecast, k

    def current(self, k: int) -> Forecast | None:
        """The latest forecast as seen at frame k (its first k - latest_at steps dropped)."""
        return None if self.latest is None else shift_forecast(self.latest, k - self.latest_at)


def shift_forecast(forecast: Forecast, k: int) -> Forecast:
    """The forecast as seen k frames after it was made (its first k steps dropped)."""
    if k <= 0:
        return forecast
    return Forecast(agent_id=forecast.agent_id, mean=forecast.mean[:, k:], dt=forecast.dt,
                    sigma_rho=None if forecast.sigma_rho is None else forecast.sigma_rho[:, k:])
