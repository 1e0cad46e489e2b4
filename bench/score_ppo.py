"""Closed-loop scorecard of the PPO policy (bench/train_ppo.py) beside the sampling planner's egos.

On `highway_mixed_dense` (the scenario the policy was trained on), the same seeds for every ego:
the shipped PPO policy driving through `PolicyPlanner`, and the sampling planner fed TraPHic,
constant velocity and the oracle (on highway the oracle steps a copy of the live simulator: exact
futures). Scored by `simharness.closedloop.score_episode` from the recorded Scene, mean [95% bootstrap
CI] by `aggregate`; writes each ego's aggregate (--out/EGO.json) and the table of all egos scored
there on the same seeds and duration (--out/scorecard.txt).

Usage: python bench/score_ppo.py [--seeds 0-9] [--duration 30] [--egos ppo,traphic,const-vel,oracle]
                                 [--policy simharness/policies/ppo_highway_dense.zip] [--out runs/bench/score_ppo]
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
    score_episode,
    scorecard_table,
    simulate,
)
from simharness.policy_planner import SHIPPED, load_policy_planner  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402

EGOS = ("traphic", "const-vel", "oracle")


def policy_episode(spec, seed: int, policy: Path, config: LoopConfig) -> dict:  # noqa: ANN001
    """One closed-loop episode with the policy driving; scores as `run_episode` gives them."""
    planner = load_policy_planner(policy)
    t0 = time.perf_counter()
    scene, issued, _, timing = simulate(spec, seed, None, planner, config)
    scores = score_episode(scene, issued, config)
    loop_s = timing["sim"] + timing["predict"] + timing["plan"]
    scores.update({"seed": seed, "predictor": "ppo", "wall_s": time.perf_counter() - t0,
                   "realtime_factor": scene.num_frames * scene.dt / max(loop_s, 1e-9)})
    return scores


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", default="0-9")
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--policy", type=Path, default=SHIPPED)
    p.add_argument("--egos", default=",".join(("ppo", *EGOS)), help="comma list of ppo, traphic, const-vel, oracle")
    p.add_argument("--out", type=Path, default=Path("runs/bench/score_ppo"))
    a = p.parse_args()
    lo, _, hi = a.seeds.partition("-")
    seeds = list(range(int(lo), int(hi or lo) + 1))
    spec = prepare_spec(load_scenario("highway_mixed_dense").with_overrides({"duration": a.duration}))
    config = LoopConfig()
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    egos = [e for e in a.egos.split(",") if e]
    for ego in egos:  # each ego's aggregate lands in its own file, so egos can be scored in separate runs
        if ego == "ppo":
            eps = [policy_episode(spec, s, a.policy, config) for s in seeds]
        else:
            eps = [run_episode(EpisodeJob(spec, s, ego, config, keep_scene=False))["scores"] for s in seeds]
        (a.out / f"{ego}.json").write_text(json.dumps({"spec": spec.name, "duration": a.duration, "seeds": seeds,
                                                       "policy": str(a.policy) if ego == "ppo" else None,
                                                       "scores": aggregate(eps)}, default=float) + "\n")
        print(f"{ego} done {time.time() - t0:.0f} s", flush=True)
    results = {}
    for ego in ("ppo", *EGOS):
        f = a.out / f"{ego}.json"
        if f.is_file():
            got = json.loads(f.read_text())
            if got["seeds"] == seeds and got["duration"] == a.duration:
                results[ego] = got["scores"]
    table = scorecard_table(results)
    print(table)
    (a.out / "scorecard.txt").write_text(table + "\n")


if __name__ == "__main__":
    main()
