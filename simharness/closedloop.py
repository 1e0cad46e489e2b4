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

import dataclasses
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.metrics import collisions, comfort, displacement, safety
from simharness.planners import (
    BackgroundPlanner,
    ConstantSpeedPlanner,
    EgoLimits,
    Planner,
    SamplingPlanner,
    rows_of,
)
from simharness.scenario import ScenarioSpec, load_scenario
from simharness.scene import AgentType, Forecast, Predictor, Scene
from simharness.sim.base import Frame, RoadGeometry, scene_from_frames

REFERENCE_EGOS = ("oracle", "static", "none", "blind")  # not predictors: handled here, not by load_predictor
SCALARS = ("collided", "collisions", "at_fault_collided", "at_fault_collisions", "phantom_braking_s", "near_miss",
           "near_misses_per_min", "min_gap_m", "background_collisions", "background_collisions_per_1000_agent_min",
           "progress_m", "mean_speed", "time_stuck_s", "accel_rms", "jerk_rms", "lat_accel_max", "online_ade",
           "online_fde", "online_ade_rmse", "online_fde_rmse", "realtime_factor")


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


@dataclasses.dataclass
class _Issued:
    """Forecasts issued during an episode (for online error and animations)."""

    frames: list[int] = dataclasses.field(default_factory=list)
    forecasts: list[Forecast] = dataclasses.field(default_factory=list)


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
        import copy

        targets = np.asarray(targets, int)
        clone = copy.deepcopy(self.sim)
        ids = history.agent_id[targets]
        mean = _constant_velocity(history, targets, horizon)
        for f in range(horizon):  # frames of the copy; agents matched by id inside, vectorised
            frame = clone.step(None)
            hit = rows_of(frame.agent_id, ids)
            mean[hit >= 0, f] = frame.xy[hit[hit >= 0]]
        return Forecast(agent_id=ids, mean=mean, dt=history.dt)


# ---------------------------------------------------------------------- one episode
def make_planner(name: str, spec: ScenarioSpec, road: RoadGeometry | None) -> Planner:
    """The ego behind a predictor name: 'none' -> background model, 'blind' -> constant speed, else sampling."""
    if name == "none":
        return BackgroundPlanner()
    if name == "blind":
        return ConstantSpeedPlanner()
    return SamplingPlanner(EgoLimits(max_speed=spec.road.speed_limit), road=road)


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


def simulate(spec: ScenarioSpec, seed: int, predictor: Predictor | None, planner: Planner,
             config: LoopConfig) -> tuple[Scene, _Issued, RoadGeometry, dict[str, float]]:
    """Run one closed-loop rollout; returns the recorded Scene, the forecasts issued, the road and timings (s)."""
    from simharness.sim import make_simulator

    dt = spec.dt
    hist = max(2, int(round(config.history_s / dt)))
    horizon = max(1, int(round(config.horizon_s / dt)))
    every = max(1, int(round(1.0 / (config.predict_hz * dt))))
    issued = _Issued()
    timing = {"reset": 0.0, "sim": 0.0, "predict": 0.0, "plan": 0.0}
    if hasattr(planner, "reset"):
        planner.reset()
    sim = make_simulator(spec)
    try:
        t0 = time.perf_counter()
        frames: list[Frame] = [sim.reset(seed)]
        road = sim.road
        if hasattr(planner, "set_road"):  # the drivable area is only known once the simulator is built
            planner.set_road(road)
        if isinstance(predictor, LookaheadOracle):
            predictor.sim = sim
        timing["reset"] += time.perf_counter() - t0
        ego_frames, latest, latest_at = 0, None, -1
        for k in range(spec.num_frames - 1):
            frame = frames[-1]
            ego_frames = ego_frames + 1 if frame.ego >= 0 else 0
            command = None
            if ego_frames >= 2 and not isinstance(planner, BackgroundPlanner):
                t1 = time.perf_counter()
                if predictor is not None and (latest is None or k - latest_at >= every):
                    history = _history(frames[-hist:], dt, k + 1 - min(hist, len(frames)), config.radius)
                    targets = np.flatnonzero(history.valid[:, -1] & (np.arange(history.num_agents) != history.ego))
                    latest = predictor.predict(history, targets, horizon) if targets.size else None
                    latest_at = k
                    if latest is not None:
                        issued.frames.append(k)
                        issued.forecasts.append(latest)
                t2 = time.perf_counter()
                now = _scene_of(frame, dt)
                command = planner.plan(now, _shift(latest, k - latest_at) if latest is not None else None)
                timing["predict"] += t2 - t1
                timing["plan"] += time.perf_counter() - t2
            t3 = time.perf_counter()
            frames.append(sim.step(command))
            timing["sim"] += time.perf_counter() - t3
    finally:
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


def _scene_of(frame: Frame, dt: float) -> Scene:
    """One frame as a one-column Scene (the planner's "now"), built directly: no id matching needed."""
    return Scene(xy=frame.xy[:, None], heading=frame.heading[:, None], speed=frame.speed[:, None],
                 valid=np.ones((frame.num_agents, 1), bool), agent_id=frame.agent_id, agent_type=frame.agent_type,
                 length=frame.length, width=frame.width, dt=dt, ego=frame.ego,
                 extra={k: v[:, None] for k, v in frame.extra.items()})


def _shift(forecast: Forecast, k: int) -> Forecast:
    """The forecast as seen k frames after it was made (its first k steps dropped)."""
    if k <= 0:
        return forecast
    return Forecast(agent_id=forecast.agent_id, mean=forecast.mean[:, k:], dt=forecast.dt,
                    sigma_rho=None if forecast.sigma_rho is None else forecast.sigma_rho[:, k:])


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
    reference_s = 0.0
    if job.predictor == "static":
        predictor = StaticForecast()
    elif job.predictor == "oracle" and spec.backend in CLONABLE_BACKENDS:
        predictor = LookaheadOracle()
    elif job.predictor == "oracle":
        ref_scene, _, _, _ = simulate(spec, job.seed, None, BackgroundPlanner(), cfg)
        predictor = ReplayOracle(ref_scene)
        reference_s = time.perf_counter() - wall0
    elif job.predictor not in REFERENCE_EGOS:
        predictor = _predictor(job.predictor)
    scene, issued, road, timing = simulate(spec, job.seed, predictor, make_planner(job.predictor, spec, None), cfg)
    wall = time.perf_counter() - wall0
    scene.meta.update({"predictor": job.predictor, "scene_id": f"{_slug(job.predictor)}-seed{job.seed:06d}"})
    scores = score_episode(scene, issued, cfg)
    sim_s = scene.num_frames * scene.dt
    loop_s = timing["sim"] + timing["predict"] + timing["plan"]
    scores.update({"seed": job.seed, "predictor": job.predictor, "wall_s": wall, "sim_s": sim_s,
                   "realtime_factor": sim_s / max(loop_s, 1e-9), "reference_s": reference_s,
                   "realtime_factor_with_warmup": (sim_s + spec.warmup) / max(wall - reference_s, 1e-9),
                   **{f"time_{k}_s": v for k, v in timing.items()}})
    out: dict[str, Any] = {"scores": scores, "road": road.to_dict()}
    if job.keep_scene:
        out["scene"] = scene
    if job.keep_forecasts:
        out["forecasts"] = (issued.frames, issued.forecasts)
    return out


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in Path(name).name or name)


# ---------------------------------------------------------------------- scoring
def score_episode(scene: Scene, issued: _Issued, config: LoopConfig) -> dict[str, Any]:
    """Per-episode figures from the recorded Scene and the forecasts issued (see `SCALARS`)."""
    e = scene.ego
    dt = scene.dt
    out: dict[str, Any] = {"ego_present": e >= 0}
    nan = math.nan
    if e < 0:
        out.update({k: nan for k in SCALARS})
        out["first_collision_t"] = None
        out["collisions_by_type"] = {t.label: 0 for t in AgentType}
        out["online_by_type"] = {}
        return out
    xy, hd, ln, wd, va = scene.xy, scene.heading, scene.length, scene.width, scene.valid
    bh = collisions.box_heading(scene)
    contact = safety.ego_contact(xy, bh, ln, wd, va, e)
    # Overlaps the simulator created when it placed the ego are its doing, not the ego's: set apart.
    first = int(np.argmax(va[e]))
    placed = np.zeros_like(contact)
    placed[:, first:] = np.cumprod(contact[:, first:], axis=1).astype(bool)
    contact &= ~placed
    vel = scene.speed[..., None] * np.stack([np.cos(hd), np.sin(hd)], -1)
    ttc = safety.time_to_collision(xy, vel, bh, ln, wd, va, e, horizon=config.ttc_horizon)
    near = safety.near_misses(ttc, contact, va, config.ttc_threshold)
    gap = safety.min_gap(xy, bh, ln, wd, va, e)
    bg = safety.background_collisions(xy, bh, ln, wd, va, e)
    ego_minutes = va[e].sum() * dt / 60.0
    agent_minutes = (va.sum() - va[e].sum()) * dt / 60.0
    by_type = safety.collisions_by_type(contact, scene.agent_type)
    phantom = safety.phantom_braking(xy, scene.speed, bh, ln, wd, va, e, dt)
    fault = safety.ego_at_fault(safety.spell_onsets(contact), xy, vel, hd, wd, va, e, phantom=phantom)
    out.update({
        "collided": float(contact.any()),
        "insertion_overlaps": int(placed[:, first].sum()),
        "collisions": float(sum(by_type.values())),
        "collisions_by_type": by_type,
        "at_fault_collided": float(fault.any()),
        "at_fault_collisions": float(fault.sum()),
        "phantom_braking_s": float(phantom.sum() * dt),
        "first_collision_t": float(scene.times[np.flatnonzero(contact.any(0))[0]]) if contact.any() else None,
        "near_miss": float(near.any()),
        "near_misses_per_min": float(near.sum() / max(ego_minutes, 1e-9)),
        "min_gap_m": float(gap.min()) if np.isfinite(gap).any() else nan,
        "min_ttc_s": float(ttc.min()) if np.isfinite(ttc).any() else None,
        "background_collisions": float(len(bg)),
        "background_collisions_per_1000_agent_min": float(1000 * len(bg) / max(agent_minutes, 1e-9)),
        "progress_m": comfort.progress(xy[e], hd[e], va[e]),
        "mean_speed": float(scene.speed[e][va[e]].mean()),
        "time_stuck_s": comfort.time_stuck(scene.speed[e], va[e], dt, config.stuck_speed),
        "ego_seconds": float(va[e].sum() * dt),
    })
    c = comfort.comfort_summary(scene.speed[e], hd[e], va[e], dt)
    out.update({k: c[k] for k in ("accel_rms", "jerk_rms", "lat_accel_max", "accel_max", "jerk_max")})
    out.update(online_errors(scene, issued))
    return out


def online_errors(scene: Scene, issued: _Issued) -> dict[str, Any]:
    """Each issued forecast against what the agents did next: ADE/FDE both ways, overall and per type."""
    keys = ("online_ade", "online_fde", "online_ade_rmse", "online_fde_rmse")
    if not issued.forecasts:
        return {**dict.fromkeys(keys, math.nan), "online_samples": 0, "online_by_type": {}}
    horizon = min(f.horizon for f in issued.forecasts)
    preds, truths, valids, types = [], [], [], []
    for k, f in zip(issued.frames, issued.forecasts, strict=True):  # one entry per forecast, arrays inside
        rows = rows_of(scene.agent_id, f.agent_id)
        cols = k + 1 + np.arange(horizon)
        inside = cols < scene.num_frames
        cc = np.minimum(cols, scene.num_frames - 1)
        ok = (rows[:, None] >= 0) & inside[None] & scene.valid[np.maximum(rows, 0)][:, cc]
        preds.append(f.mean[:, :horizon])
        truths.append(scene.xy[np.maximum(rows, 0)][:, cc])
        valids.append(ok)
        types.append(scene.agent_type[np.maximum(rows, 0)])
    pred, truth, valid = np.concatenate(preds), np.concatenate(truths), np.concatenate(valids)
    s = displacement.summary(pred, truth, valid)
    groups = displacement.by_group(pred, truth, valid, np.concatenate(types), {t.value: t.label for t in AgentType})
    return {"online_ade": s["ade"], "online_fde": s["fde"], "online_ade_rmse": s["ade_rmse"],
            "online_fde_rmse": s["fde_rmse"], "online_samples": s["samples"], "online_by_type": groups}


# ---------------------------------------------------------------------- over seeds
def bootstrap_ci(values: Sequence[float], resamples: int = 2000, level: float = 0.95, seed: int = 0
                 ) -> dict[str, float | int]:
    """Mean and percentile-bootstrap confidence interval of the finite values (seeded).

    values (E,) -> {"mean", "lo", "hi", "n"}; nan everywhere when no finite value.
    """
    x = np.asarray([v for v in values if v is not None], np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"mean": math.nan, "lo": math.nan, "hi": math.nan, "n": 0}
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, (resamples, x.size))].mean(1)
    a = (1 - level) / 2
    return {"mean": float(x.mean()), "lo": float(np.quantile(means, a)), "hi": float(np.quantile(means, 1 - a)),
            "n": int(x.size)}


_RENAMED = ("collided", "at_fault_collided", "near_miss", "progress_m", "online_ade", "online_fde",
            "online_ade_rmse", "online_fde_rmse")


def aggregate(episodes: Sequence[dict[str, Any]], seed: int = 0) -> dict[str, Any]:
    """Scores over episodes: each scalar's mean with a 95% bootstrap CI; the issue's keys first.

    collision_rate: share of episodes in which the ego collided; near_miss_rate: share with a near miss.
    """
    present = [e for e in episodes if e.get("ego_present")]
    col = {k: bootstrap_ci([e[k] for e in present], seed=seed) for k in SCALARS}
    by_type: dict[str, Any] = {}
    for t in AgentType:
        counts = [e["collisions_by_type"][t.label] for e in present]
        by_type[t.label] = {"total": int(sum(counts)), **bootstrap_ci(counts, seed=seed)}
    online_types = sorted({k for e in present for k in e.get("online_by_type", {})})
    online_by_type = {
        t: {m: bootstrap_ci([e["online_by_type"][t][m] for e in present if t in e["online_by_type"]], seed=seed)
            for m in ("ade", "fde", "ade_rmse", "fde_rmse")} for t in online_types}
    return {
        "episodes": len(episodes),
        "episodes_with_ego": len(present),
        "seeds": sorted(int(e["seed"]) for e in episodes),
        "collision_rate": col["collided"],
        "collisions_by_type": by_type,
        "at_fault_collision_rate": col["at_fault_collided"],
        "near_miss_rate": col["near_miss"],
        "progress_m": col["progress_m"],
        "online_ade": col["online_ade"],
        "online_fde": col["online_fde"],
        "online_ade_rmse": col["online_ade_rmse"],
        "online_fde_rmse": col["online_fde_rmse"],
        "online_by_type": online_by_type,
        **{k: v for k, v in col.items() if k not in _RENAMED},
        "bootstrap": {"resamples": 2000, "level": 0.95, "seed": seed},
    }


def run_closed_loop(spec: ScenarioSpec, predictor: str, seeds: Sequence[int], workers: int = 2,
                    executor: str = "local", address: str | None = None, config: LoopConfig | None = None,
                    keep_forecasts: Sequence[int] = (), progress: bool = True) -> list[dict[str, Any]]:
    """Episodes of one predictor over seeds through an executor; results sorted by seed.

    Failed episodes raise SimulatorError naming the seeds (scores over a silent subset would mislead).
    """
    from tqdm import tqdm

    from simharness.errors import SimulatorError
    from simharness.executors import make_executor

    config = config or LoopConfig()
    if predictor not in REFERENCE_EGOS:
        _predictor(predictor)  # fail fast on a bad name, before any process starts
    jobs = [EpisodeJob(spec, s, predictor, config, keep_forecasts=s in set(keep_forecasts)) for s in seeds]
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


# ---------------------------------------------------------------------- CLI
def _fmt(ci: dict[str, float]) -> str:
    if not ci or not np.isfinite(ci.get("mean", math.nan)):
        return "n/a"
    return f"{ci['mean']:.2f} [{ci['lo']:.2f}, {ci['hi']:.2f}]"


SCORECARD_ROWS = (("collision_rate", "collision rate (share of episodes)"),
                  ("at_fault_collision_rate", "at-fault collision rate (share of episodes)"),
                  ("near_miss_rate", "near-miss rate (share of episodes)"),
                  ("near_misses_per_min", "near misses per ego-minute"),
                  ("progress_m", "progress (m)"), ("mean_speed", "mean speed (m/s)"),
                  ("time_stuck_s", "time stuck (s)"), ("accel_rms", "RMS acceleration (m/s^2)"),
                  ("jerk_rms", "RMS jerk (m/s^3)"), ("min_gap_m", "minimum gap (m)"),
                  ("background_collisions_per_1000_agent_min", "background collisions / 1000 agent-min"),
                  ("online_ade", "online ADE (m, mean Euclidean)"), ("online_fde", "online FDE (m, mean Euclidean)"),
                  ("online_ade_rmse", "online ADE (m, RMSE)"), ("online_fde_rmse", "online FDE (m, RMSE)"),
                  ("realtime_factor", "simulated s per wall s"))


def scorecard_table(scores: dict[str, dict[str, Any]]) -> str:
    """Plain-text scorecard: one column per ego, mean [95% CI] per row."""
    names = list(scores)
    width = 46
    lines = [f"{'':{width}}" + "".join(f"{n:>26}" for n in names)]
    lines.append(f"{'episodes':{width}}" + "".join(f"{scores[n]['episodes']:>26}" for n in names))
    for key, label in SCORECARD_ROWS:
        lines.append(f"{label:{width}}" + "".join(f"{_fmt(scores[n].get(key, {})):>26}" for n in names))
    types = [t.label for t in AgentType if any(scores[n]["collisions_by_type"][t.label]["total"] for n in names)]
    for t in types:
        lines.append(f"{'ego collisions with ' + t + ' (total)':{width}}"
                     + "".join(f"{scores[n]['collisions_by_type'][t]['total']:>26}" for n in names))
    return "\n".join(lines)


def write_run(out: Path, spec: ScenarioSpec, predictor: str, results: Sequence[dict[str, Any]], animate: int = 0
              ) -> dict[str, Any]:
    """scores.json, episodes/ (Parquet via write_dataset) and animations of one ego's episodes under `out`."""
    from simharness.io.parquet import atomic_write_bytes, dumps, software_versions, write_dataset

    out.mkdir(parents=True, exist_ok=True)
    scores = aggregate([r["scores"] for r in results])
    scores.update({"predictor": predictor, "scenario": spec.name, "reaction": spec.ego.reaction,
                   "config_hash": spec.config_hash(), "versions": software_versions(),
                   "per_episode": [r["scores"] for r in results]})
    scenes = [r["scene"] for r in results if "scene" in r]
    if scenes:
        write_dataset(scenes, out / "episodes", {"source": "closedloop", "predictor": predictor,
                                                  "scenario": spec.to_dict(), "seeds": scores["seeds"],
                                                  "config_hash": spec.config_hash(), "road": results[0]["road"]},
                      overwrite=True)
    if animate:
        from simharness.report import animate_episode

        for r in [r for r in results if "forecasts" in r][:animate]:
            frames, forecasts = r["forecasts"]
            animate_episode(r["scene"], out / f"episode-seed{r['scores']['seed']:06d}.gif",
                            road=RoadGeometry.from_dict(r["road"]), forecast_frames=frames, forecasts=forecasts)
    atomic_write_bytes(out / "scores.json", (dumps(scores, indent=1) + "\n").encode())
    return scores


def closedloop_command(args: Any) -> int:
    """`simharness closedloop SCENARIO --predictor NAME[,NAME...] --seeds 0-19`: scorecard + scores.json."""
    spec = prepare_spec(load_scenario(args.scenario), args.reaction)
    names = [n.strip() for n in str(args.predictor).split(",") if n.strip()]
    if not names:
        raise UserError("--predictor: expected a name (traphic, const-vel, oracle, none) or a run folder")
    out = Path(args.out)
    from simharness.io.folders import prepare_output

    prepare_output(out, getattr(args, "force", False))
    all_scores = {}
    for name in names:
        results = run_closed_loop(spec, name, args.seeds, args.workers, args.executor, args.address,
                                  keep_forecasts=args.seeds[: args.animate])
        folder = out if len(names) == 1 else out / _slug(name)
        all_scores[name] = write_run(folder, spec, name, results, animate=args.animate)
    if len(names) > 1:
        from simharness.io.parquet import atomic_write_bytes

        atomic_write_bytes(out / "scorecard.json", (json.dumps(
            {n: {k: v for k, v in s.items() if k != "per_episode"} for n, s in all_scores.items()},
            indent=1, default=float) + "\n").encode())
    from simharness.report import write_report

    print(f"{spec.name}: reaction {spec.ego.reaction}, {len(args.seeds)} seeds "
          f"(mean [95% bootstrap CI])")
    print(scorecard_table(all_scores))
    print(f"wrote {out / 'scores.json' if len(names) == 1 else out / 'scorecard.json'}, "
          f"report {write_report(out)}")
    return 0


def demo_closed_loop(out: Path, seeds: Sequence[int] = (0, 1), duration: float = 20.0, workers: int = 2,
                     scenario: str = "sumo_arterial_dense", reaction: str = "cut_in", extra_md: str = "") -> Path:
    """The demo's closed-loop step: TraPHic (when its weights ship), constant velocity, oracle and no
    prediction on a few seeds; prints the scorecard, writes out/closedloop/<ego>/ and out/report.md
    (with one animation). Returns the report's path."""
    from simharness.report import write_report

    spec = prepare_spec(load_scenario(scenario), reaction).with_overrides({"duration": float(duration)})
    egos = ["traphic", "const-vel", "oracle", "none"]
    try:
        _predictor("traphic")
    except (UserError, OSError) as e:
        print(f"      (TraPHic left out of the closed loop: {e})", file=sys.stderr)
        egos.remove("traphic")
    scores = {}
    for ego in egos:
        results = run_closed_loop(spec, ego, list(seeds), workers=workers,
                                  keep_forecasts=list(seeds)[:1] if ego == egos[0] else ())
        scores[ego] = write_run(Path(out) / "closedloop" / _slug(ego), spec, ego, results,
                                animate=1 if ego == egos[0] else 0)
    print(f"{spec.name}, reaction {spec.ego.reaction}, seeds {list(seeds)} x {duration:g} s "
          "(mean [95% bootstrap CI])")
    print(scorecard_table(scores))
    return write_report(out, title="simharness demo", extra_md=extra_md, closedloop_dir=Path(out) / "closedloop")
