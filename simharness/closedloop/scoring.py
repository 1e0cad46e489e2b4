"""Per-episode scores of the closed loop, from the recorded Scene only, and the online forecast error."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simharness.closedloop.config import Issued, LoopConfig
from simharness.metrics import collisions, comfort, displacement, safety
from simharness.planners import rows_of
from simharness.scene import AgentType, Scene

SCALARS = ("collided", "collisions", "at_fault_collided", "at_fault_collisions", "phantom_braking_s", "near_miss",
           "near_misses_per_min", "min_gap_m", "background_collisions", "background_collisions_per_1000_agent_min",
           "progress_m", "mean_speed", "time_stuck_s", "accel_rms", "jerk_rms", "lat_accel_max", "online_ade",
           "online_fde", "online_ade_rmse", "online_fde_rmse", "realtime_factor")



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


def online_errors(scene: Scene, issued: Issued) -> dict[str, Any]:
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

