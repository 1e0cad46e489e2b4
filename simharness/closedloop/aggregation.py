"""Scores over episodes: bootstrap CIs, the scorecard (dict and plain-text table), written as strict JSON."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from simharness.closedloop.scoring import SCALARS
from simharness.scene import AgentType


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
    """Scores over episodes (`score_episode` output, with or without `run_episode`'s seed and timings): each
    scalar's mean with a 95% bootstrap CI; a scalar an episode lacks counts as missing there.

    collision_rate: share of episodes in which the ego collided; near_miss_rate: share with a near miss.
    """
    present = [e for e in episodes if e.get("ego_present")]
    col = {k: bootstrap_ci([e.get(k) for e in present], seed=seed) for k in SCALARS}
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
        "seeds": sorted(int(e["seed"]) for e in episodes if e.get("seed") is not None),
        "collision_rate": col["collided"],
        "collisions_by_type": by_type,
        "at_fault_collision_rate": col["at_fault_collided"],
        "near_miss_rate": col["near_miss"],
        "progress_m": col["progress_m"],
        "online_ade": col["online_ade"],
        "online_fde": col["online_fde"],
        "online_ade_rmse": col["online_ade_rmse"],
        "online_fde_rmse": col["online_fde_rmse"],
        "forecast_coverage": col["forecast_coverage"],
        "online_by_type": online_by_type,
        **{k: v for k, v in col.items() if k not in _RENAMED},
        "bootstrap": {"resamples": 2000, "level": 0.95, "seed": seed},
    }



def _fmt(ci: dict[str, float]) -> str:
    if not ci or not np.isfinite(ci.get("mean", math.nan)):
        return "n/a"
    return f"{ci['mean']:.2f} [{ci['lo']:.2f}, {ci['hi']:.2f}]"


SCORECARD_ROWS = (("composite", "composite score (0-1, docs/closedloop.md)"),
                  ("collision_rate", "collision rate (share of episodes)"),
                  ("at_fault_collision_rate", "at-fault collision rate (share of episodes)"),
                  ("near_miss_rate", "near-miss rate (share of episodes)"),
                  ("near_misses_per_min", "near misses per ego-minute"),
                  ("progress_m", "progress (m)"), ("progress_ratio", "progress / traffic flow's (capped at 1)"),
                  ("left_drivable", "left the drivable area (share of episodes)"), ("mean_speed", "mean speed (m/s)"),
                  ("time_stuck_s", "time stuck (s)"), ("accel_rms", "RMS acceleration (m/s^2)"),
                  ("jerk_rms", "RMS jerk (m/s^3)"), ("min_gap_m", "minimum gap (m)"),
                  ("background_collisions_per_1000_agent_min", "background collisions / 1000 agent-min"),
                  ("online_ade", "online ADE (m, mean Euclidean)"),
                  ("forecast_coverage", "forecast coverage (share of agents in range)"),
                  ("online_fde", "online FDE (m, mean Euclidean)"),
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



def finite_json(obj: Any) -> Any:
    """obj with every NaN or infinite number replaced by None (and numpy values by plain ones), recursively,
    so that it serialises as strict JSON (`null`, never the bare NaN / Infinity tokens)."""
    if isinstance(obj, dict):
        return {str(k): finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite_json(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


def strict_dumps(obj: Any, indent: int | None = 1) -> str:
    """Strict JSON text (sorted keys; NaN and infinities as null; paths and other objects as strings)."""
    return json.dumps(finite_json(obj), sort_keys=True, indent=indent, allow_nan=False, default=str)
