"""Closed-loop scorecard of a trained policy (bench/train_ppo.py) beside the prediction-driven planner.

The same held-out seeds for every ego (training never resets the simulator with them): the policy
driving through `PolicyPlanner` (its episode ends at its first collision, as in its gym env), and the
default prediction-driven planner fed each predictor named in --egos (const-vel, traphic, oracle).
Every episode is run by `simharness.closedloop.run_episode` and scored by `score_episode` from the
recorded Scene; mean [95% bootstrap CI] by `aggregate`. Writes each ego's aggregate (--out/EGO.json)
and the table of the egos scored there on the same scenario, seeds and duration (--out/scorecard.txt).
`simharness closedloop SCENARIO --planner ppo --seeds 100-109` scores the shipped policy the same way.

Usage: python bench/score_ppo.py [--scenario highway_mixed_dense] [--seeds 100-109] [--duration 60]
                                 [--egos ppo,const-vel] [--policy simharness/policies/ppo_highway_dense.zip]
                                 [--out runs/bench/score_ppo]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# bench/ holds a script named predictor.py: keep it from shadowing the `predictor` package.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

from simharness.closedloop import (  # noqa: E402
    EpisodeJob,
    LoopConfig,
    aggregate,
    prepare_spec,
    run_episode,
    scorecard_table,
)
from simharness.policy_planner import SHIPPED  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="highway_mixed_dense")
    p.add_argument("--seeds", default="100-109", help="held-out seeds, e.g. 100-109")
    p.add_argument("--duration", type=float, default=None, help="seconds per episode (default: the scenario's)")
    p.add_argument("--policy", type=Path, default=SHIPPED)
    p.add_argument("--egos", default="ppo,const-vel", help="comma list: ppo (the policy) and predictor names")
    p.add_argument("--out", type=Path, default=Path("runs/bench/score_ppo"))
    a = p.parse_args()
    lo, _, hi = a.seeds.partition("-")
    seeds = list(range(int(lo), int(hi or lo) + 1))
    spec = load_scenario(a.scenario)
    spec = prepare_spec(spec.with_overrides({"duration": a.duration}) if a.duration else spec)
    config = LoopConfig()
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    egos = [e for e in a.egos.split(",") if e]
    for ego in egos:  # each ego's aggregate lands in its own file, so egos can be scored in separate runs
        if ego == "ppo":  # the loop's forecasts are not the policy's input; const-vel is the cheapest to make
            jobs = [EpisodeJob(spec, s, "const-vel", config, keep_scene=False, planner=str(a.policy)) for s in seeds]
        else:
            jobs = [EpisodeJob(spec, s, ego, config, keep_scene=False) for s in seeds]
        eps = [run_episode(job)["scores"] for job in jobs]
        (a.out / f"{ego}.json").write_text(json.dumps({"spec": spec.name, "duration": spec.duration, "seeds": seeds,
                                                       "policy": str(a.policy) if ego == "ppo" else None,
                                                       "scores": aggregate(eps)}, default=float) + "\n")
        print(f"{ego} done {time.time() - t0:.0f} s", flush=True)
    results = {}
    for f in sorted(a.out.glob("*.json")):
        got = json.loads(f.read_text())
        if got.get("seeds") == seeds and got.get("duration") == spec.duration and got.get("spec") == spec.name:
            results["ppo policy" if f.stem == "ppo" else f"planner + {f.stem}"] = got["scores"]
    table = scorecard_table(results)
    print(table)
    (a.out / "scorecard.txt").write_text(table + "\n")


if __name__ == "__main__":
    main()
