"""Planner benchmark: the closed loop's planner (`PDMPlanner`) against the sampling planner, paired on the same seeds.

1. Milliseconds per plan of each planner on the same recorded (frame, forecast) pairs: one constant-velocity
   episode of a stress scenario, every planner call replayed through both planners.
2. Simulated seconds per second of the closed loop (loop wall time; and CPU time of the whole episode, warm-up and the
   oracle's branches included) with TraPHic and with the exact oracle driving each planner over the same seeds, and
   the at-fault / comfortable / near-miss rates.

    .venv/bin/python bench/planner.py                                   # cut_in, seeds 1000-1003
    .venv/bin/python bench/planner.py --scenario scenarios/stress/brake.toml --seeds 1000-1009
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

from simharness.closedloop import episode  # noqa: E402
from simharness.closedloop.config import EpisodeJob, LoopConfig  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402

KINDS = ("pdm", "sampling")


def plan_times(spec, seed: int) -> dict[str, float]:
    """ms per plan of each planner on the planner calls of one constant-velocity episode."""
    calls = []
    live = episode.make_planner("const-vel", spec, None)

    class Recorder:
        def reset(self) -> None:
            live.reset()

        def set_road(self, road) -> None:
            live.set_road(road)

        def plan(self, now, forecast):
            calls.append((now, forecast))
            return live.plan(now, forecast)

    _, _, road, _ = episode.simulate(spec, seed, episode._predictor("const-vel"), Recorder(), LoopConfig())
    out = {}
    for kind in KINDS:
        planner = episode.make_planner("const-vel", spec, road, kind)
        planner.plan(*calls[0])  # compiled kernels loaded
        planner.reset()
        t0 = time.perf_counter()
        for now, forecast in calls:
            planner.plan(now, forecast)
        out[kind] = (time.perf_counter() - t0) / len(calls) * 1e3
    return out


def loop(spec, seeds: list[int], predictor: str, kind: str) -> dict[str, float]:
    """Realtime factors (simulated s per loop wall s; per CPU s of the whole episode, warm-up included: the
    figure that holds on a busy machine) and rates over the seeds."""
    rows = [episode.run_episode(EpisodeJob(spec, s, predictor, LoopConfig(), keep_scene=False, planner=kind))["scores"]
            for s in seeds]
    loop_s = sum(r["time_sim_s"] + r["time_predict_s"] + r["time_plan_s"] for r in rows)
    return {"realtime": sum(r["sim_s"] for r in rows) / loop_s, "per_cpu": sum(r["sim_s"] for r in rows)
            / sum(r["cpu_s"] for r in rows),
            **{k: float(np.mean([r[k] for r in rows])) for k in ("at_fault_collided", "comfortable", "near_miss",
                                                                  "composite")}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="scenarios/stress/cut_in.toml")
    ap.add_argument("--seeds", default="1000-1003")
    args = ap.parse_args()
    lo, hi = (int(x) for x in args.seeds.split("-"))
    seeds = list(range(lo, hi + 1))
    spec = episode.prepare_spec(load_scenario(args.scenario))
    times = plan_times(spec, seeds[0])
    print(f"{spec.name}: ms per plan, the same {args.seeds.split('-')[0]} const-vel episode's calls: "
          + ", ".join(f"{k} {v:.2f}" for k, v in times.items()))
    for predictor in ("traphic", "oracle"):
        for kind in KINDS:
            r = loop(spec, seeds, predictor, kind)
            print(f"{spec.name} {predictor:8s} {kind:9s} realtime {r['realtime']:6.2f}x (loop, wall), "
                  f"{r['per_cpu']:6.2f}x (episode incl. warm-up, CPU)  at-fault "
                  f"{r['at_fault_collided']:.2f}  comfortable {r['comfortable']:.2f}  near miss {r['near_miss']:.2f}  "
                  f"composite {r['composite']:.3f}  (seeds {args.seeds})")


if __name__ == "__main__":
    main()
