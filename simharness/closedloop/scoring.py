"""Per-episode scores of the closed loop, from the recorded Scene only; the online forecast error; the
composite closed-loop score (nuPlan's closed-loop score adapted; formula in docs/closedloop.md).

Composite, per episode (E episodes vectorise: every input (E,), output (E,)):

    score = (1 - at_fault_collided) * (1 - left_drivable) * making_progress
            * (5 * progress_ratio + 5 * ttc_ok + 2 * comfortable) / 12

- at_fault_collided: the ego caused a collision (`safety.ego_at_fault`: ran into someone ahead, or
  moved across the flow into them; being rear-ended or cut into while holding its line is not its fault);
- left_drivable: a corner of the ego's box (shrunk by `DRIVABLE_TOLERANCE`) left the drivable area;
- progress_ratio: the ego's progress over the traffic flow's (the mean speed of the vehicles within
  `FLOW_RADIUS` m of the ego times the ego's time), capped at 1; making_progress: progress_ratio >= 0.2;
- ttc_ok: no near miss (time-to-collision never below `LoopConfig.ttc_threshold`, to agents not behind the moving
  ego: `safety.ttc_relevant`, nuPlan's selection);
- comfortable: peak |acceleration|, |jerk| and |lateral acceleration| within `COMFORT_BOUNDS` (nuPlan's), from the
  ego's first commanded frame on (the simulator drives its first frame).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simharness.closedloop.config import Issued, LoopConfig
from simharness.metrics import collisions, comfort, displacement, safety
from simharness.planners import rows_of
from simharness.scene import AgentType, Scene, heading_velocity
from simharness.sim.base import RoadGeometry

SCALARS = ("collided", "collisions", "at_fault_collided", "at_fault_collisions", "phantom_braking_s", "near_miss",
           "near_misses_per_min", "min_gap_m", "background_collisions", "background_collisions_per_1000_agent_min",
           "progress_m", "mean_speed", "time_stuck_s", "accel_rms", "jerk_rms", "lat_accel_max", "online_ade",
           "online_fde", "online_ade_rmse", "online_fde_rmse", "realtime_factor", "composite", "left_drivable",
           "progress_ratio", "ttc_ok", "comfortable", "forecast_coverage")

COMPOSITE_WEIGHTS = {"progress": 5.0, "ttc": 5.0, "comfort": 2.0}  # nuPlan's weights for these three
COMFORT_BOUNDS = {"accel_max": 4.05, "jerk_max": 8.37, "lat_accel_max": 4.89}  # m/s^2, m/s^3 (nuPlan's)
MIN_PROGRESS_RATIO = 0.2  # below this share of the flow's progress the episode scores 0 (nuPlan's)
FLOW_RADIUS = 30.0  # m: the vehicles whose speed is the traffic flow the ego's progress is measured against
NUPLAN_TTC = 0.95  # s: nuPlan's near-miss threshold (`near_miss_nuplan`, reported beside the scorecard's own)
DRIVABLE_TOLERANCE = 0.2  # m: the ego's box is shrunk by this before testing it against the drivable area


# ---------------------------------------------------------------------- the composite score
def composite_score(at_fault_collided: np.ndarray, left_drivable: np.ndarray, progress_ratio: np.ndarray,
                    ttc_ok: np.ndarray, comfortable: np.ndarray) -> np.ndarray:
    """The composite closed-loop score in [0, 1] (module docstring). All inputs (E,) (bool or 0/1 floats;
    progress_ratio in [0, 1]) -> (E,) float; a nan input gives nan."""
    w = COMPOSITE_WEIGHTS
    ratio = np.asarray(progress_ratio, np.float64)
    gate = (1.0 - np.asarray(at_fault_collided, np.float64)) * (1.0 - np.asarray(left_drivable, np.float64))
    gate = gate * np.where(np.isnan(ratio), np.nan, ratio >= MIN_PROGRESS_RATIO)
    avg = (w["progress"] * ratio + w["ttc"] * np.asarray(ttc_ok, np.float64)
           + w["comfort"] * np.asarray(comfortable, np.float64)) / sum(w.values())
    return gate * avg


def flow_progress(xy: np.ndarray, speed: np.ndarray, agent_type: np.ndarray, valid: np.ndarray, ego: int,
                  dt: float, radius: float = FLOW_RADIUS) -> float:
    """Metres the traffic around the ego covered in the ego's time: the mean speed of the vehicles
    (pedestrians left out) within `radius` m of the ego over the ego's frames, times the ego's seconds.

    xy (N, T, 2) m, speed (N, T) m/s, agent_type (N,), valid (N, T), ego row -> m; nan without any such vehicle.
    """
    near = valid & valid[ego][None] & (np.linalg.norm(xy - xy[ego][None], axis=-1) <= radius)
    near[ego] = False
    near &= (agent_type != int(AgentType.PEDESTRIAN))[:, None]
    if not near.any():
        return math.nan
    return float(speed[near].mean() * max(int(valid[ego].sum()) - 1, 0) * dt)  # frames span (n - 1) dt


def off_drivable(xy: np.ndarray, heading: np.ndarray, length: float, width: float, valid: np.ndarray,
                 road: RoadGeometry, tolerance: float = DRIVABLE_TOLERANCE) -> np.ndarray:
    """(T,) bool: frames where a corner of the ego's box, shrunk by `tolerance` m, is off the drivable area.

    xy (T, 2) m, heading (T,) rad (the body's), length / width m, valid (T,); a road without drivable
    polygons is taken as everywhere drivable.
    """
    if not road.drivable:
        return np.zeros(valid.shape, bool)
    ln, wd = np.full(len(xy), max(length - 2 * tolerance, 0.0)), np.full(len(xy), max(width - 2 * tolerance, 0.0))
    corners = collisions.box_corners(xy, heading, ln, wd)  # (T, 4, 2)
    return valid & ~road.on_road(corners).all(-1)




def score_episode(scene: Scene, issued: Issued, config: LoopConfig) -> dict[str, Any]:
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
    vel = heading_velocity(scene.speed, hd)
    ttc = safety.time_to_collision(xy, vel, bh, ln, wd, va, e, horizon=config.ttc_horizon)
    ttc = np.where(safety.ttc_relevant(xy, bh, scene.speed, va, e), ttc, np.inf)  # nuPlan's: not behind, ego moving
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
        "near_miss_nuplan": float(safety.near_misses(ttc, contact, va, NUPLAN_TTC).any()),
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
    # Comfort from the ego's first commanded frame on: the simulator drives its first frame (the hand-over is not
    # the planner's doing; the first command's jerk would be measured against the simulator's own acceleration).
    driven = va[e].copy()
    driven[first] = False
    c = comfort.comfort_summary(scene.speed[e], hd[e], driven, dt)
    out.update({k: c[k] for k in ("accel_rms", "jerk_rms", "lat_accel_max", "accel_max", "jerk_max")})
    road = RoadGeometry.from_dict(scene.meta["road"]) if "road" in scene.meta else RoadGeometry()
    flow = flow_progress(xy, scene.speed, scene.agent_type, va, e, dt)
    out["flow_progress_m"] = flow
    out["progress_ratio"] = 1.0 if not flow > 0 else float(np.clip(out["progress_m"] / flow, 0.0, 1.0))
    out["left_drivable"] = float(off_drivable(xy[e], bh[e], float(ln[e]), float(wd[e]), va[e], road).any())
    out["ttc_ok"] = 1.0 - out["near_miss"]
    out["comfortable"] = float(all(c[k] <= b for k, b in COMFORT_BOUNDS.items()))
    out["composite"] = float(composite_score(out["at_fault_collided"], out["left_drivable"], out["progress_ratio"],
                                             out["ttc_ok"], out["comfortable"]))
    out.update(online_errors(scene, issued))
    # share of the agents in range, over the prediction steps, that got a forecast (nan: never asked)
    out["forecast_coverage"] = issued.answered / issued.asked if issued.asked else nan
    return out


def issued_truth(scene: Scene, issued: Issued) -> tuple[np.ndarray, ...]:
    """Every target of every issued forecast beside what it then did, over the shortest forecast's horizon F.

    -> pred, truth (S, F, 2) m; valid (S, F) bool (recorded, inside the episode); rows (S,) int, the target's row in
    `scene` (-1 where it is not there: valid all False); frames (S,) int, the frame the forecast was made at.
    """
    horizon = min(f.horizon for f in issued.forecasts)
    preds, truths, valids, rows_all, frames = [], [], [], [], []
    for k, f in zip(issued.frames, issued.forecasts, strict=True):  # one entry per forecast, arrays inside
        rows = rows_of(scene.agent_id, f.agent_id)
        cols = k + 1 + np.arange(horizon)
        inside = cols < scene.num_frames
        cc = np.minimum(cols, scene.num_frames - 1)
        preds.append(f.mean[:, :horizon])
        truths.append(scene.xy[np.maximum(rows, 0)][:, cc])
        valids.append((rows[:, None] >= 0) & inside[None] & scene.valid[np.maximum(rows, 0)][:, cc])
        rows_all.append(rows)
        frames.append(np.full(rows.size, k))
    return tuple(np.concatenate(a) for a in (preds, truths, valids, rows_all, frames))


def online_errors(scene: Scene, issued: Issued) -> dict[str, Any]:
    """Each issued forecast against what the agents did next: ADE/FDE both ways, overall and per type."""
    keys = ("online_ade", "online_fde", "online_ade_rmse", "online_fde_rmse")
    if not issued.forecasts:
        return {**dict.fromkeys(keys, math.nan), "online_samples": 0, "online_by_type": {}}
    pred, truth, valid, rows, _ = issued_truth(scene, issued)
    s = displacement.summary(pred, truth, valid)
    groups = displacement.by_group(pred, truth, valid, scene.agent_type[np.maximum(rows, 0)],
                                   {t.value: t.label for t in AgentType})
    return {"online_ade": s["ade"], "online_fde": s["fde"], "online_ade_rmse": s["ade_rmse"],
            "online_fde_rmse": s["fde_rmse"], "online_samples": s["samples"], "online_by_type": groups}

