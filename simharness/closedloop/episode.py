"""The closed loop: Simulator + Predictor + Planner -> recorded Scene + scores, over seeds.

One episode (`run_episode`, the job function; pools call it, it knows nothing of them):
reset the scenario with its ego enabled, then every recorded frame
- while the ego is absent (before `ego.insert_at`) or has < 2 frames of history, step with None;
- at each prediction step (`predict_hz`) the predictor gets the last `history_s` of every agent
  within `radius` of the ego (a Scene built from the recorded frames) and forecasts all of them but
  the ego over `horizon_s`;
- at every frame the planner turns the latest forecast (shifted by the frames elapsed since it was
  made) into an `EgoCommand`.
Every frame is recorded; the episode is scored from the recorded Scene only (oriented-box overlaps,
never the simulator's own flags) and each forecast is scored against what the agents really did.

Egos by `predictor` name: a registered predictor or run folder (traphic, const-vel, ...) drives the
sampling planner; "oracle" feeds it the true future (below); "static" feeds it no prediction (everyone
stays put: the planner's floor); "none" lets the simulator's own background model drive the ego (no
prediction at all); "blind" holds speed and line whatever happens (a test reference).

"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.closedloop.config import EpisodeJob, Issued, LoopClock, LoopConfig
from simharness.closedloop.oracles import BranchOracle, StaticForecast, scene_of
from simharness.closedloop.perturbations import Perturbation, PerturbedPredictor
from simharness.closedloop.scoring import score_episode
from simharness.errors import UserError
from simharness.planners import (
    BackgroundPlanner,
    ConstantSpeedPlanner,
    EgoLimits,
    Planner,
    SamplingPlanner,
    rows_of,
)
from simharness.scenario import ScenarioSpec
from simharness.scene import Predictor, Scene
from simharness.sim.base import Frame, RoadGeometry, scene_from_frames

REFERENCE_EGOS = ("oracle", "static", "none", "blind")  # not predictors: handled here, not by load_predictor


# ---------------------------------------------------------------------- one episode
def make_planner(name: str, spec: ScenarioSpec, road: RoadGeometry | None) -> Planner:
    """The ego behind a predictor name: 'none' -> background model, 'blind' -> constant speed, else sampling."""
    if name == "none":
        return BackgroundPlanner()
    if name == "blind":
        return ConstantSpeedPlanner()
    return SamplingPlanner(EgoLimits(max_speed=spec.road.speed_limit), road=road)


def make_oracle(spec: ScenarioSpec, config: LoopConfig) -> BranchOracle:
    """The exact oracle for a scenario: forecast and planning horizons in the scenario's frames."""
    from simharness.planners import SamplingConfig

    dt = spec.dt
    return BranchOracle(dt, horizon=max(1, int(round(config.horizon_s / dt))),
                        plan_frames=max(1, int(round(SamplingConfig().horizon_s / dt))), radius=config.radius,
                        window=int(round(config.oracle_window_s / dt)))


def _predictor(name: str) -> Predictor:
    try:
        from simharness.predictors import load_predictor
    except ImportError as e:  # pragma: no cover - the registry ships with the package
        raise UserError(f"--predictor {name}: the predictor registry is not available ({e})") from None
    return load_predictor(name)


def prepare_spec(spec: ScenarioSpec, reaction: str | None = None) -> ScenarioSpec:
    """The scenario with its ego enabled (and the background's reaction overridden if given)."""
    changes: dict[str, Any] = {} if spec.ego.enabled else {"ego.enabled": True}
    if reaction is not None and reaction != spec.ego.reaction:
        changes["ego.reaction"] = reaction
    return spec.with_overrides(changes) if changes else spec


def simulate(spec: ScenarioSpec, seed: int, predictor: Predictor | BranchOracle | None, planner: Planner,
             config: LoopConfig) -> tuple[Scene, Issued, RoadGeometry, dict[str, float]]:
    """Run one closed-loop rollout; returns the recorded Scene, the forecasts issued, the road and timings (s).

    A `BranchOracle` is handed the live simulator, planner and clock instead of a history (it branches them).
    """
    from simharness.sim import make_simulator

    dt = spec.dt
    hist = max(2, int(round(config.history_s / dt)))
    horizon = max(1, int(round(config.horizon_s / dt)))
    clock = LoopClock(every=max(1, int(round(1.0 / (config.predict_hz * dt)))))
    issued = Issued()
    timing = {"reset": 0.0, "sim": 0.0, "predict": 0.0, "plan": 0.0}
    if hasattr(planner, "reset"):
        planner.reset()
    perturbed = predictor if isinstance(predictor, PerturbedPredictor) else None
    oracle = isinstance(getattr(predictor, "inner", predictor), BranchOracle)
    sim = make_simulator(spec, process=oracle)  # SUMO branches by forking its worker process
    if oracle and perturbed is not None:  # the branches' egos are served what the live planner is
        perturbed.inner.serve = perturbed.degrader
    try:
        t0 = time.perf_counter()
        frames: list[Frame] = [sim.reset(seed)]
        road = sim.road
        if hasattr(planner, "set_road"):  # the drivable area is only known once the simulator is built
            planner.set_road(road)
        timing["reset"] += time.perf_counter() - t0
        for k in range(spec.num_frames - 1):
            frame = frames[-1]
            command = None
            if clock.tick(frame.ego >= 0) and not isinstance(planner, BackgroundPlanner):
                t1 = time.perf_counter()
                if predictor is not None and clock.due(k):
                    if oracle:
                        forecast = (perturbed.inner if perturbed else predictor).forecast(k, frame, sim, planner, clock)
                        if perturbed is not None and forecast is not None:  # degrade what the live planner is served
                            rows = rows_of(frame.agent_id, forecast.agent_id)
                            forecast = perturbed.degrade(forecast, frame.xy[rows], frame.agent_type[rows], k, horizon)
                    else:
                        history = _history(frames[-hist:], dt, k + 1 - min(hist, len(frames)), config.radius)
                        targets = np.flatnonzero(history.valid[:, -1] & (np.arange(history.num_agents) != history.ego))
                        forecast = predictor.predict(history, targets, horizon) if targets.size else None
                    clock.issue(k, forecast)
                    if forecast is not None:
                        issued.frames.append(k)
                        issued.forecasts.append(forecast)
                t2 = time.perf_counter()
                command = planner.plan(scene_of(frame, dt), clock.current(k))
                timing["predict"] += t2 - t1
                timing["plan"] += time.perf_counter() - t2
            t3 = time.perf_counter()
            frames.append(sim.step(command))
            timing["sim"] += time.perf_counter() - t3
    finally:
        if oracle:
            getattr(predictor, "inner", predictor).close()  # its kept branch's snapshots
        sim.close()
    meta = {"source": "closedloop", "scenario": spec.name, "seed": int(seed), "backend": spec.backend,
            "config_hash": spec.config_hash(), "road": road.to_dict()}
    return scene_from_frames(frames, dt, meta), issued, road, timing


def _history(frames: Sequence[Frame], dt: float, frame0: int, radius: float) -> Scene:
    """Last frames as a Scene (frame0 = index of its first frame in the episode), agents near the ego only."""
    scene = scene_from_frames(frames, dt).replace(frame0=frame0)
    ego_xy = scene.xy[scene.ego, -1]
    near = scene.valid[:, -1] & (np.linalg.norm(scene.xy[:, -1] - ego_xy, axis=-1) <= radius)
    near[scene.ego] = True
    return scene.select_agents(near)


def run_episode(job: EpisodeJob) -> dict[str, Any]:
    """The job function: one episode -> {"scores", "scene" (optional), "forecasts" (optional), "road"}."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover - torch is a dependency
        pass
    spec, cfg = job.spec, job.config
    wall0 = time.perf_counter()
    predictor: Predictor | None = None
    if job.predictor == "static":
        predictor = StaticForecast()
    elif job.predictor == "oracle":
        predictor = make_oracle(spec, cfg)
    elif job.predictor not in REFERENCE_EGOS:
        predictor = _predictor(job.predictor)
    if job.perturbation is not None and predictor is not None and not job.perturbation.is_identity:
        predictor = PerturbedPredictor(predictor, job.perturbation, seed=job.seed)
    scene, issued, road, timing = simulate(spec, job.seed, predictor, make_planner(job.predictor, spec, None), cfg)
    wall = time.perf_counter() - wall0
    scene.meta.update({"predictor": job.predictor, "scene_id": f"{_slug(job.predictor)}-seed{job.seed:06d}"})
    scores = score_episode(scene, issued, cfg)
    sim_s = scene.num_frames * scene.dt
    loop_s = timing["sim"] + timing["predict"] + timing["plan"]
    scores.update({"seed": job.seed, "predictor": job.predictor, "wall_s": wall, "sim_s": sim_s,
                   "realtime_factor": sim_s / max(loop_s, 1e-9),
                   "realtime_factor_with_warmup": (sim_s + spec.warmup) / max(wall, 1e-9),
                   **{f"time_{k}_s": v for k, v in timing.items()}})
    if isinstance(getattr(predictor, "inner", predictor), BranchOracle):
        scores.update({f"oracle_{k}": v for k, v in getattr(predictor, "inner", predictor).stats.items()})
    out: dict[str, Any] = {"scores": scores, "road": road.to_dict()}
    if job.keep_scene:
        out["scene"] = scene
    if job.keep_forecasts:
        out["forecasts"] = (issued.frames, issued.forecasts)
    return out


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in Path(name).name or name)



def run_closed_loop(spec: ScenarioSpec, predictor: str, seeds: Sequence[int], workers: int = 2,
                    executor: str = "local", address: str | None = None, config: LoopConfig | None = None,
                    keep_forecasts: Sequence[int] = (), progress: bool = True,
                    perturbation: Perturbation | None = None) -> list[dict[str, Any]]:
    """Episodes of one predictor over seeds through an executor; results sorted by seed.

    Failed episodes raise SimulatorError naming the seeds (scores over a silent subset would mislead).
    """
    from tqdm import tqdm

    from simharness.errors import SimulatorError
    from simharness.executors import make_executor

    config = config or LoopConfig()
    if predictor not in REFERENCE_EGOS:
        _predictor(predictor)  # fail fast on a bad name, before any process starts
    jobs = [EpisodeJob(spec, s, predictor, config, keep_forecasts=s in set(keep_forecasts),
                       perturbation=perturbation) for s in seeds]
    results, failed = [], []
    bar = tqdm(total=len(jobs), desc=f"closedloop {predictor}", unit="ep", file=sys.stderr, disable=not progress)
    for r in make_executor(executor, workers, address).map_unordered(run_episode, jobs):
        bar.update(1)
        if r.ok:
            results.append(r.value)
            bar.set_postfix(rt=f"{r.value['scores']['realtime_factor']:.1f}x")
        else:
            failed.append(f"seed {r.job.seed}: {r.error}")
    bar.close()
    if failed:
        raise SimulatorError(f"{spec.name}, predictor {predictor}: {len(failed)} episode(s) failed: "
                             + "; ".join(failed[:3]))
    return sorted(results, key=lambda r: r["scores"]["seed"])

