"""What one closed-loop episode is given (`LoopConfig`, `EpisodeJob`) and what it records (`Issued`)."""

from __future__ import annotations

import dataclasses

from simharness.closedloop.perturbations import Perturbation
from simharness.scenario import ScenarioSpec
from simharness.scene import Forecast


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """How the loop feeds the predictor and scores the episode."""

    history_s: float = 3.0  # seconds of history given to the predictor
    horizon_s: float = 5.0  # seconds forecast
    predict_hz: float = 2.5  # predictor calls per second; the planner replans every frame
    radius: float = 60.0  # m: agents this close to the ego are given to the predictor
    ttc_threshold: float = 1.5  # s: near miss below this time-to-collision
    ttc_horizon: float = 5.0  # s: time-to-collision extrapolation horizon
    stuck_speed: float = 0.5  # m/s: the ego counts as stuck below this speed


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


@dataclasses.dataclass
class Issued:
    """Forecasts issued during an episode (for online error and animations)."""

    frames: list[int] = dataclasses.field(default_factory=list)
    forecasts: list[Forecast] = dataclasses.field(default_factory=list)
