"""The exact oracle: online ADE / FDE per backend x background reaction, and its cost per episode.

Each forecast the oracle makes during an episode is compared with what the agents then did in that
same episode (the loop's online error). Printed per scenario x reaction: mean online ADE and FDE
(m; the target is < 0.05 m), the worst episode's, the oracle's branches / iterations / cycles /
inexact forecasts (blends served where no fixed point exists) / mismatches per episode, wall seconds per
episode and simulated seconds per wall second (loop only; target >= 5x real time on one core on SUMO).

    .venv/bin/python bench/oracle.py                          # 10 seeds x 60 s (the results page's figures)
    .venv/bin/python bench/oracle.py --seeds 0-2 --duration 20  # a quick look
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# bench/ holds a script named predictor.py: keep it from shadowing the `predictor` package.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

from simharness.cli import parse_seeds  # noqa: E402
from simharness.closedloop import EpisodeJob, prepare_spec, run_episode  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402

SCENARIOS = ("sumo_arterial_dense", "highway_mixed_dense")
REACTIONS = ("reactive", "cut_in", "ignore")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", default=",".join(SCENARIOS))
    p.add_argument("--reactions", default=",".join(REACTIONS))
    p.add_argument("--seeds", type=parse_seeds, default=list(range(10)), help="e.g. 0-9")
    p.add_argument("--duration", type=float, default=60.0, help="recorded seconds per episode")
    args = p.parse_args()
    print(f"== exact oracle: {len(args.seeds)} seeds x {args.duration:g} s, one episode at a time on one core")
    print(f"{'scenario':22}{'reaction':10}{'ADE':>8}{'FDE':>8}{'max ADE':>9}{'max FDE':>9}{'branches':>9}"
          f"{'iters':>7}{'cycles':>7}{'inexact':>8}{'mism.':>7}{'wall s/ep':>10}{'x real':>8}")
    for name in args.scenarios.split(","):
        for reaction in args.reactions.split(","):
            spec = prepare_spec(load_scenario(name), reaction).with_overrides({"duration": args.duration})
            rows = []
            for seed in args.seeds:
                t0 = time.perf_counter()
                s = run_episode(EpisodeJob(spec, seed, "oracle", keep_scene=False))["scores"]
                rows.append({**s, "wall": time.perf_counter() - t0})
            ade = np.array([r["online_ade"] for r in rows])
            fde = np.array([r["online_fde"] for r in rows])
            per = {k: np.mean([r[f"oracle_{k}"] for r in rows])
                   for k in ("branches", "iterations", "cycles", "inexact", "mismatches")}
            sim_s = sum(r["sim_s"] for r in rows)
            loop_s = sum(r["time_sim_s"] + r["time_predict_s"] + r["time_plan_s"] for r in rows)
            print(f"{name:22}{reaction:10}{np.nanmean(ade):8.4f}{np.nanmean(fde):8.4f}{np.nanmax(ade):9.4f}"
                  f"{np.nanmax(fde):9.4f}{per['branches']:9.1f}{per['iterations']:7.1f}{per['cycles']:7.1f}"
                  f"{per['inexact']:8.1f}{per['mismatches']:7.1f}{np.mean([r['wall'] for r in rows]):10.1f}"
                  f"{sim_s / loop_s:8.2f}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
