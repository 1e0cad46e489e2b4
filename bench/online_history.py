"""A predictor's online error in the closed loop, split by the target's history when it was forecast.

Each forecast issued during an episode is scored against what the target then did (mean Euclidean ADE over
the forecast's horizon, m), grouped by: the target's recorded history (full: the loop's `history_s`; partial:
less, in the episode's first `history_s` or because it had just appeared) and its distance to the ego (under or
over 20 m). The table behind "Session 5: short histories in the loop" in docs/results.md.

    .venv/bin/python bench/online_history.py --scenario stress/brake --predictors traphic,const-vel --seeds 0-2
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simharness.cli import parse_seeds  # noqa: E402
from simharness.closedloop.config import LoopConfig  # noqa: E402
from simharness.closedloop.episode import make_planner, prepare_spec, simulate  # noqa: E402
from simharness.closedloop.scoring import issued_truth  # noqa: E402
from simharness.predictors import load_predictor  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402

NEAR_M = 20.0


def errors_by_history(scenario: str, predictor: str, seeds: list[int]) -> dict[tuple[str, str], list[float]]:
    """{(history, distance): [ADE of each forecast target]} over the episodes of `seeds`."""
    spec, cfg = prepare_spec(load_scenario(scenario)), LoopConfig()
    pred = load_predictor(predictor)
    hist = int(round(cfg.history_s / spec.dt))
    bins: dict[tuple[str, str], list[float]] = {}
    for seed in seeds:
        scene, issued, _, _ = simulate(spec, seed, pred, make_planner(predictor, spec, None), cfg)
        mean, truth, valid, rows, frames = issued_truth(scene, issued)
        r = np.maximum(rows, 0)
        recorded = np.concatenate([np.zeros((scene.num_agents, 1), int), np.cumsum(scene.valid, 1)], 1)  # (N, T + 1)
        seen = recorded[r, frames + 1] - recorded[r, np.maximum(frames + 1 - hist, 0)]  # frames in each history
        far = np.linalg.norm(scene.xy[r, frames] - scene.xy[scene.ego, frames], axis=-1) >= NEAR_M
        err = np.linalg.norm(mean - truth, axis=-1)
        for i in np.flatnonzero(valid.any(1)):
            key = ("full" if seen[i] >= hist else ("partial, k < history" if frames[i] < hist else "partial, later"),
                   f">= {NEAR_M:g} m" if far[i] else f"< {NEAR_M:g} m")
            bins.setdefault(key, []).append(float(err[i][valid[i]].mean()))
    return bins


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="stress/brake")
    ap.add_argument("--predictors", default="traphic,const-vel")
    ap.add_argument("--seeds", default="0-2")
    args = ap.parse_args()
    seeds = parse_seeds(args.seeds)
    print("| scenario | predictor | target history | distance to ego | forecasts | online ADE (m) |")
    print("|---|---|---|---|---|---|")
    for name in args.predictors.split(","):
        for key, errs in sorted(errors_by_history(args.scenario, name, seeds).items()):
            print(f"| {args.scenario} | {name} | {key[0]} | {key[1]} | {len(errs)} | {np.mean(errs):.2f} |")


if __name__ == "__main__":
    main()
