"""Simulator backends behind one protocol (`simharness.sim.base.Simulator`)."""

from __future__ import annotations

from simharness.scenario import ScenarioSpec
from simharness.sim.base import EgoCommand, Event, Frame, RoadGeometry, Simulator, scene_from_frames

__all__ = ["EgoCommand", "Event", "Frame", "RoadGeometry", "Simulator", "make_simulator", "scene_from_frames"]


def make_simulator(spec: ScenarioSpec, process: bool = False) -> Simulator:
    """The backend the scenario names; imported lazily so one backend's deps never load the other.

    process: for sumo, run libsumo in a worker process (`SumoProcess`: any number per process, and
    `branch()`); the highway and replay backends are plain Python and always run in this process.
    """
    if spec.backend == "sumo" and process:
        from simharness.sim.sumo.process import SumoProcess

        return SumoProcess(spec)
    if spec.backend == "sumo":
        from simharness.sim.sumo.simulator import SumoSimulator

        return SumoSimulator(spec)
    if spec.backend == "highway":
        from simharness.sim.highway.simulator import HighwaySimulator

        return HighwaySimulator(spec)
    if spec.backend == "replay":
        from simharness.sim.replay.simulator import ReplaySimulator

        return ReplaySimulator(spec)
    raise ValueError(f"unknown backend {spec.backend!r}")  # the scenario loader already checked
