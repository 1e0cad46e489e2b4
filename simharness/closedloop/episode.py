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
planner (`PDMPlanner`; `make_planner(..., kind="sampling")`: the sampling planner); "oracle" feeds it
the true future (below); "static" feeds it no prediction (everyone
stays put: the planner's floor); "none" lets the simulator's own background model drive the ego (no
prediction at all); "blind" holds speed and line whatever happens (a test reference).
A planner that sets `ended` (a `PolicyPlanner` at its first collision) ends the recording there, as its
gym env terminates the episode; the shorter Scene is scored like any other.

"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.closedloop.config import EpisodeJob, Issued, LoopClock, LoopConfig
from simharness.closedloop.oracles import BranchOracle, StaticForecast, near_targets, scene_of
from simharness.closedloop.perturbations import Perturbation, PerturbedPredictor
from simharness.closedloop.scoring import score_episode
from simharness.closedloop.validation import answered, validate_forecast
from simharness.errors import UserError
from simharness.pdm_planner import PDMConfig, PDMPlanner
from simharness.planners import (
    BackgroundPlanner,
    ConstantSpeedPlanner,
    EgoLimits,
    Planner,
    SamplingPlanner,
    rows_of,
)
from simharness.scenario import ScenarioSpec
from simharness.scene import Forecast, Predictor, Scene
from simharness.sim.base import Frame, RoadGeometry, scene_from_frames

REFERENCE_EGOS = ("oracle", "static", "none", "blind")  # not predictors: handled here, not by load_predictor


# ---------------------------------------------------------------------- one episode
def make_planner(name: str, spec: ScenarioSpec, road: RoadGeometry | None, kind: str = "pdm") -> Planner:
    """The ego behind a predictor name: 'none' -> background model, 'blind' -> constant speed, else the
    prediction-driven planner `kind`: 'pdm' (`PDMPlanner`, the default), 'sampling' (`SamplingPlanner`) or any other
    planner name (`simharness.plugins.load_planner`: 'ppo', a policy .zip, file.py:NAME, module:NAME)."""
    if name == "none":
        return BackgroundPlanner()
    if name == "blind":
        return ConstantSpeedPlanner()
    limits = EgoLimits(max_speed=spec.road.speed_limit)
    if kind == "sampling":
        return SamplingPlanner(limits, road=road)
    if kind != "pdm":
        from simharness.plugins import load_planner

        return load_planner(kind, spec, road)
    return PDMPlanner(limits, road=road)


def make_oracle(spec: ScenarioSpec, config: LoopConfig) -> BranchOracle:
    """The exact oracle for a scenario: forecast and planning horizons in the scenario's frames."""
    from simharness.planners import SamplingConfig

    dt = spec.dt
    return BranchOracle(dt, horizon=max(1, int(round(config.horizon_s / dt))),
                        plan_frames=max(1, int(round(SamplingConfig().horizon_s / dt))), radius=config.radius,
                        window=int(round(config.oracle_window_s / dt)))


def _predictor(name: str) -> Predictor:
    """A predictor by name (`simharness.plugins.load_predictor`); an unknown name's error lists the reference egos."""
    from simharness.plugins import load_predictor

    return load_predictor(name, references=REFERENCE_EGOS)


def prepare_spec(spec: ScenarioSpec, reaction: str | None = None) -> ScenarioSpec:
    """The scenario with its ego enabled (and the background's reaction overridden if given)."""
    changes: dict[str, Any] = {} if spec.ego.enabled else {"ego.enabled": True}
    if spec.backend == "replay" and reaction is not None:  # a recording replayed: log playback, or reacting
        if reaction not in ("log", "ignore", "reactive"):
            raise UserError(f"--reaction {reaction}: a replayed recording's agents either replay the log (log) or "
                            "react to the ego (reactive)")
        mode = "reactive" if reaction == "reactive" else "log"
        return spec.with_overrides({**changes, "replay.mode": mode}) if changes or mode != spec.replay.mode else spec
    if reaction == "log":
        raise UserError(f"--reaction log: {spec.name} is simulated, not a replayed recording; expected reactive, "
                        "cut_in or ignore")
    if reaction is not None and reaction != spec.ego.reaction:
        changes["ego.reaction"] = reaction
    return spec.with_overrides(changes) if changes else spec


def reaction_of(spec: ScenarioSpec) -> str:
    """How the background treats the ego: the scenario's reaction, or a replay's mode (log / reactive)."""
    return spec.replay.mode if spec.backend == "replay" else spec.ego.reaction


def simulate(spec: ScenarioSpec, seed: int, predictor: Predictor | BranchOracle | None, planner: Planner,
             config: LoopConfig, name: str = "predictor") -> tuple[Scene, Issued, RoadGeometry, dict[str, float]]:
    """Run one closed-loop rollout; returns the recorded Scene, the forecasts issued, the road and timings (s).

    A `BranchOracle` is handed the live simulator, planner and clock instead of a history (it branches them).
    A predictor's forecasts are validated (`validation.validate_forecast`; UserError naming `name`).
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
                        asked = frame.agent_id[near_targets(frame, config.radius)]
                    else:
                        history = _history(frames[-hist:], dt, k + 1 - min(hist, len(frames)), config.radius)
                        targets = np.flatnonzero(history.valid[:, -1] & (np.arange(history.num_agents) != history.ego))
                        asked = history.agent_id[targets]
                        forecast = _predict(predictor, history, targets, horizon, name) if targets.size else None
                    issued.asked += len(asked)
                    issued.answered += answered(forecast, asked)
                    clock.issue(k, forecast)
                    if forecast is not None:
                        issued.frames.append(k)
                        issued.forecasts.append(forecast)
                t2 = time.perf_counter()
                command = planner.plan(scene_of(frame, dt), clock.current(k))
                timing["predict"] += t2 - t1
                timing["plan"] += time.perf_counter() - t2
                if getattr(planner, "ended", False):  # a policy's episode ends at its collision, as in its env
                    break
            t3 = time.perf_counter()
            frames.append(sim.step(command))
            timing["sim"] += time.perf_counter() - t3
            if at_road_end(frames, road, spec.road.speed_limit * PDMConfig().horizon_s + 5.0):
                break  # completed: the ego reached the end of its road (scored on the frames so far)
    finally:
        if oracle:
            getattr(predictor, "inner", predictor).close()  # its kept branch's snapshots
        sim.close()
    meta = {"source": "closedloop", "scenario": spec.name, "seed": int(seed), "backend": spec.backend,
            "config_hash": spec.config_hash(), "road": road.to_dict()}
    return scene_from_frames(frames, dt, meta), issued, road, timing


def _predict(predictor: Predictor, history: Scene, targets: np.ndarray, horizon: int, name: str) -> Forecast:
    """The predictor's forecast of history's rows `targets` over `horizon` frames, validated."""
    try:
        forecast = predictor.predict(history, targets, horizon)
    except ValueError as e:  # a Forecast built with inconsistent shapes refuses itself
        if not str(e).startswith("Forecast."):
            raise
        raise UserError(f"predictor {name!r}: {e}") from None
    return validate_forecast(forecast, name, history.agent_id[targets], horizon)


def at_road_end(frames: Sequence[Frame], road: RoadGeometry, reach: float) -> bool:
    """Whether the ego has reached the end of its road: it was in the last-but-one frame and has left the
    simulation, or no corner of the drivable area lies more than `reach` m ahead of it along its heading (the
    planner's proposals would run off the road's end, so the episode ends there, as completed)."""
    f = frames[-1]
    if f.ego < 0:
        return len(frames) >= 2 and frames[-2].ego >= 0
    if not road.drivable:
        return False
    h = float(f.heading[f.ego])
    ahead = (np.concatenate(road.drivable) - f.xy[f.ego]) @ np.array([np.cos(h), np.sin(h)])
    return bool(ahead.max() < reach)


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
    wall0, cpu0 = time.perf_counter(), _cpu_seconds()
    predictor: Predictor | None = None
    if job.predictor == "static":
        predictor = StaticForecast()
    elif job.predictor == "oracle":
        predictor = make_oracle(spec, cfg)
    elif job.predictor not in REFERENCE_EGOS:
        predictor = _predictor(job.predictor)
    if job.perturbation is not None and predictor is not None and not job.perturbation.is_identity:
        predictor = PerturbedPredictor(predictor, job.perturbation, seed=job.seed)
    planner = make_planner(job.predictor, spec, None, job.planner)
    scene, issued, road, timing = simulate(spec, job.seed, predictor, planner, cfg, name=job.predictor)
    wall = time.perf_counter() - wall0
    scene.meta.update({"predictor": job.predictor, "scene_id": f"{_slug(job.predictor)}-seed{job.seed:06d}"})
    scores = score_episode(scene, issued, cfg)
    sim_s = scene.num_frames * scene.dt
    loop_s = timing["sim"] + timing["predict"] + timing["plan"]
    scores.update({"seed": job.seed, "predictor": job.predictor, "planner": job.planner, "wall_s": wall, "sim_s": sim_s,
                   "cpu_s": _cpu_seconds() - cpu0,
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


def _cpu_seconds() -> float:
    """CPU seconds of this process and of its finished children (a SUMO worker, the oracle's forked branches)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def raise_user_error(error: str | None) -> None:
    """Re-raise, as the one line it was, a UserError that a job raised in a worker process (bad input, such as an
    invalid forecast, is the user's to fix: not an episode that failed)."""
    if error and error.startswith("UserError: "):
        raise UserError(error.removeprefix("UserError: "))


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in Path(name).name or name)



def run_closed_loop(spec: ScenarioSpec, predictor: str, seeds: Sequence[int], workers: int = 2,
                    executor: str = "local", address: str | None = None, config: LoopConfig | None = None,
                    keep_forecasts: Sequence[int] = (), progress: bool = True,
                    perturbation: Perturbation | None = None, planner: str = "pdm") -> list[dict[str, Any]]:
    """Episodes of one predictor over seeds through an executor; results sorted by seed. planner: the ego's
    planner by name (`make_planner`).

    Failed episodes raise SimulatorError naming the seeds (scores over a silent subset would mislead).
    """
    from tqdm import tqdm

    from simharness.errors import SimulatorError
    from simharness.executors import make_executor

    config = config or LoopConfig()
    if predictor not in REFERENCE_EGOS:
        _predictor(predictor)  # fail fast on a bad name, before any process starts
    make_planner(predictor, spec, None, planner)  # and on a bad planner
    jobs = [EpisodeJob(spec, s, predictor, config, keep_forecasts=s in set(keep_forecasts),
                       perturbation=perturbation, planner=planner) for s in seeds]
    results, failed = [], []
    bar = tqdm(total=len(jobs), desc=f"closedloop {predictor}", unit="ep", file=sys.stderr, disable=not progress)
    for r in make_executor(executor, workers, address).map_unordered(run_episode, jobs):
        bar.update(1)
        if r.ok:
            results.append(r.value)
            bar.set_postfix(rt=f"{r.value['scores']['realtime_factor']:.1f}x")
        else:
            if r.error.startswith("UserError: "):
                bar.close()  # the one line comes after the bar, not before its last redraw
                raise_user_error(r.error)
            failed.append(f"seed {r.job.seed}: {r.error}")
    bar.close()
    if failed:
        raise SimulatorError(f"{spec.name}, predictor {predictor}: {len(failed)} episode(s) failed: "
                             + "; ".join(failed[:3]))
    return sorted(results, key=lambda r: r["scores"]["seed"])

