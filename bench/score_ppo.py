"""Closed-loop scorecard of trained policies (bench/train_ppo.py) beside the prediction-driven planner, paired.

The same held-out seeds for every ego (training never resets the simulator with them): each policy driving
through `PolicyPlanner` (its episode ends at its first collision, as in its gym env), and the default
prediction-driven planner fed each predictor named in --egos (const-vel, traphic, oracle). Every episode is
run by `simharness.closedloop.run_closed_loop` (--workers processes) and scored from the recorded Scene;
mean [95% bootstrap CI] by `aggregate`. Then each ego minus the first (and each --pairs A:B), paired on
seeds (`simharness.closedloop.paired`): collision, at-fault, composite and progress differences with 95% CIs.
Writes each ego's aggregate and episodes (--out/EGO.json), the table and the paired lines
(--out/scorecard.txt). `simharness closedloop SCENARIO --planner ppo --seeds 100-109` scores the shipped
policy the same way.

--egos: comma list of ppo (the shipped policy), NAME=PATH.zip (a policy) and predictor names, e.g.
``const-vel,ppo,fc=runs/ppo_cv.zip``.

Usage: python bench/score_ppo.py [--scenario highway_mixed_dense] [--seeds 100-109] [--duration 60]
                                 [--egos const-vel,ppo] [--pairs A:B] [--workers 2] [--out runs/bench/score_ppo]
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

from simharness.closedloop import aggregate, prepare_spec, scorecard_table  # noqa: E402
from simharness.closedloop.episode import run_closed_loop  # noqa: E402
from simharness.closedloop.paired import paired_values, stratified_ci, verdict  # noqa: E402
from simharness.policy_planner import SHIPPED  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402

PAIRED_KEYS = (("collided", "collision"), ("at_fault_collided", "at-fault"), ("composite", "composite"),
               ("progress_m", "progress (m)"))


def parse_egos(text: str) -> dict[str, tuple[str, str]]:
    """--egos -> {label: (predictor, planner)}: a policy drives with const-vel forecasts it ignores (the cheapest)."""
    egos = {}
    for item in (e.strip() for e in text.split(",")):
        if not item:
            continue
        name, _, path = item.partition("=")
        if name == "ppo" and not path:
            egos["ppo"] = ("const-vel", str(SHIPPED))
        elif path:
            egos[name] = ("const-vel", path)
        else:
            egos[f"planner + {name}"] = (name, "pdm")
    return egos


def paired_lines(episodes: dict[str, list[dict]], pairs: list[tuple[str, str]]) -> list[str]:
    """A minus B for each (A, B) of `pairs`, paired on seeds: mean difference [95% CI] and verdict per PAIRED_KEYS."""
    lines = []
    for name, base in pairs:
        parts = []
        for key, label in PAIRED_KEYS:
            _, a, b = paired_values(episodes[name], episodes[base], key)
            d = stratified_ci([a - b])
            said = verdict(name, base, d, key) if key != "progress_m" else f"n = {d['n']}"
            parts.append(f"{label} {d['mean']:+.3f} [{d['lo']:+.3f}, {d['hi']:+.3f}] ({said})")
        lines.append(f"{name} minus {base}: " + "; ".join(parts))
    return lines


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="highway_mixed_dense")
    p.add_argument("--seeds", default="100-109", help="held-out seeds, e.g. 100-109")
    p.add_argument("--duration", type=float, default=None, help="seconds per episode (default: the scenario's)")
    p.add_argument("--egos", default="const-vel,ppo", help="comma list: ppo, NAME=PATH.zip, predictor names")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--pairs", default="", help="more paired comparisons, e.g. fc:none,fc2:none (A minus B)")
    p.add_argument("--out", type=Path, default=Path("runs/bench/score_ppo"))
    a = p.parse_args()
    lo, _, hi = a.seeds.partition("-")
    seeds = list(range(int(lo), int(hi or lo) + 1))
    spec = load_scenario(a.scenario)
    spec = prepare_spec(spec.with_overrides({"duration": a.duration}) if a.duration else spec)
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    egos = parse_egos(a.egos)
    first = next(iter(egos))
    pairs = [(name, first) for name in list(egos)[1:]]
    pairs += [tuple(x.split(":")) for x in a.pairs.split(",") if x]  # type: ignore[misc]
    bad = sorted({n for pair in pairs for n in pair} - set(egos))
    if bad or any(len(pair) != 2 for pair in pairs):
        p.error(f"--pairs: expected A:B of ego labels among {', '.join(egos)}; got {bad or a.pairs}")
    results, episodes = {}, {}
    for label, (predictor, planner) in egos.items():
        eps = [r["scores"] for r in run_closed_loop(spec, predictor, seeds, a.workers, planner=planner,
                                                      progress=False)]
        results[label], episodes[label] = aggregate(eps), eps
        slug = label.replace(" ", "_").replace("+", "").replace("__", "_")
        (a.out / f"{slug}.json").write_text(json.dumps({"spec": spec.name, "duration": spec.duration, "seeds": seeds,
                                                        "planner": planner, "predictor": predictor,
                                                        "scores": results[label], "episodes": eps},
                                                       default=float) + "\n")
        print(f"{label} done {time.time() - t0:.0f} s", flush=True)
    text = "\n".join([f"{spec.name}, seeds {a.seeds}, {spec.duration:.0f} s (mean [95% bootstrap CI])",
                      scorecard_table(results), "", *paired_lines(episodes, pairs)])
    print(text)
    (a.out / "scorecard.txt").write_text(text + "\n")


if __name__ == "__main__":
    main()
