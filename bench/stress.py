"""Stress-suite benchmark: `simharness stress` (every `scenarios/stress/*.toml`, every ego on the same seeds,
paired verdicts against constant velocity) and what it costs, plus the open loop beside it.

1. Closed loop through `simharness.closedloop.suite.run_suite`: the leaderboard (Markdown, strict JSON, figure)
   under --out; then episodes per CPU-minute of each ego (process time of the worker running the episode, so
   the figure does not depend on how many workers share the machine) and the loop's real-time factor, and per
   scenario whether it discriminates: oracle at-fault rate <= 0.02, static >= 0.30, constant velocity strictly
   between. The scenarios were tuned on seeds 1000+; the scored seeds default to 0-49.
2. Open loop (--open-loop-seeds): data generated from each scenario (the ego on the simulator's own model) and
   each forecasting predictor scored on it (--split all): ADE/FDE beside the closed-loop ranks.

    .venv/bin/python bench/stress.py --seeds 0-9 --predictors traphic,oracle,const-vel   # episodes / CPU-minute
    .venv/bin/python bench/stress.py --seeds 0-49 --predictors oracle,traphic,const-vel,static,none
    .venv/bin/python bench/stress.py --predictors traphic,const-vel --until-resolved --budget-minutes 30
    .venv/bin/python bench/stress.py --seeds 0-19 --predictors traphic,cs-lstm,const-vel --open-loop-seeds 0-9
    .venv/bin/python bench/stress.py --sensitivity step_out --predictors oracle --perturb noise=0,1,2,4 --seeds 0-19
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

from simharness.cli import parse_seeds  # noqa: E402
from simharness.closedloop import prepare_spec  # noqa: E402
from simharness.closedloop.suite import SuiteSettings, run_suite, stress_scenarios, write_suite  # noqa: E402
from simharness.scenario import SCENARIO_DIR, load_scenario  # noqa: E402

STRESS = sorted(p.stem for p in (SCENARIO_DIR / "stress").glob("*.toml"))


def run_jobs(jobs: list, workers: int, desc: str) -> list[dict]:
    """Episodes' scores through `workers` processes, in job order (the sensitivity grid)."""
    from simharness.closedloop.episode import raise_user_error
    from simharness.closedloop.sensitivity import run_scores
    from simharness.executors import make_executor

    results = {}
    for r in make_executor("local", workers).map_unordered(run_scores, jobs):
        raise_user_error(r.error)
        if not r.ok:
            raise RuntimeError(f"{desc}: {r.error}")
        results[id(r.job)] = r.value
    return [results[id(j)] for j in jobs]


def open_loop(scenario: str, predictors: dict[str, str], seeds: list[int], workers: int,
              out: Path) -> dict[str, dict]:
    """Open-loop ADE/FDE of each forecasting predictor on data generated from the scenario (cached)."""
    from simharness.evaluation import evaluate
    from simharness.generation import generate
    from simharness.predictors import load_predictor

    data = out / "data" / scenario
    generate(load_scenario(f"stress/{scenario}"), seeds, data, workers=workers, progress=False)
    res = {}
    for name, spec in predictors.items():
        path = out / "openloop" / scenario / f"{name}.json"
        if not path.is_file():
            m = evaluate(data, load_predictor(spec), split="all", progress=False, name=name)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps({k: m[k] for k in ("ade", "fde", "ade_rmse", "fde_rmse", "samples")},
                                       default=float) + "\n")
        res[name] = json.loads(path.read_text())
    return res


def fmt(ci: dict | None) -> str:
    if not ci or not ci.get("n"):
        return "n/a"
    return f"{ci['mean']:.2f} [{ci['lo']:.2f}, {ci['hi']:.2f}]"


def discriminates(rows: dict[str, dict]) -> str:
    """The stress suite's criterion on the at-fault rate: oracle <= 0.02, static >= 0.30, const-vel between."""
    need = ("oracle", "static", "const-vel")
    if not all(k in rows for k in need):
        return "n/a"
    o, s, c = (rows[k]["at_fault_collided"]["mean"] for k in need)
    ok = o <= 0.02 and s >= 0.30 and o < c < s
    return f"{'yes' if ok else 'NO'} (oracle {o:.2f}, const-vel {c:.2f}, static {s:.2f})"


def cost(result: dict) -> str:
    """Episodes per CPU-minute and the loop's real-time factor (simulated s per loop s, median) of each ego."""
    import numpy as np

    lines = []
    for ego in result["info"]["egos"]:
        eps = [e for rows in result["episodes"].values() for e in rows[ego]]
        cpu = sum(e["cpu_s"] for e in eps)
        rt = float(np.median([e["realtime_factor"] for e in eps]))
        wall = float(np.mean([e["wall_s"] for e in eps]))
        lines.append(f"{ego:12} {len(eps):5d} episodes  {60 * len(eps) / cpu:7.1f} episodes / CPU-minute  "
                     f"{wall:5.2f} s / episode (wall, warm-up included)  loop {rt:5.1f}x real time (median)")
    return "\n".join(lines)


def sensitivity_run(scenario: str, predictor: str, perturb: list[str], seeds: list[int], workers: int,
                    out: Path) -> dict:
    """`simharness sensitivity` through the long-lived pool: writes out/sensitivity/<scenario>/."""
    from simharness.closedloop import LoopConfig
    from simharness.closedloop.perturbations import parse_grid
    from simharness.closedloop.sensitivity import markdown_table, sensitivity_jobs, summarise, write_outputs

    spec = load_scenario(f"stress/{scenario}")
    grid = parse_grid(perturb)
    jobs = sensitivity_jobs(spec, predictor, grid, seeds)
    t0 = time.perf_counter()
    scores = run_jobs(jobs, workers, f"sensitivity {scenario}")
    by_label: dict[str, list[dict]] = {p.label(): [] for p in grid}
    for job, sc in zip(jobs, scores, strict=True):
        by_label[job.perturbation.label()].append(sc)
    result = summarise(prepare_spec(spec), predictor, grid, seeds, LoopConfig(), by_label, time.perf_counter() - t0)
    write_outputs(out / "sensitivity" / scenario, result)
    print(f"Sensitivity of {scenario} ({predictor}), seeds {seeds[0]}-{seeds[-1]}; monotone: {result['monotone']}")
    print(markdown_table(result))
    return result


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", default=",".join(STRESS), help="stress scenario names (default: all)")
    p.add_argument("--predictors", default="oracle,traphic,const-vel,static,none", help="egos, comma-separated")
    p.add_argument("--seeds", type=parse_seeds, default=None, help="default 0-49 (0-999 with --until-resolved)")
    p.add_argument("--until-resolved", action="store_true", help="as `simharness stress --until-resolved`")
    p.add_argument("--budget-minutes", type=float, default=30.0)
    p.add_argument("--target", type=float, default=0.03)
    p.add_argument("--batch", type=int, default=20)
    p.add_argument("--open-loop-seeds", type=parse_seeds, default=None, help="also score open loop on these seeds")
    p.add_argument("--open-loop-predictors", default="traphic,cs-lstm,const-vel", help="comma-separated")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/bench_stress"))
    p.add_argument("--sensitivity", default=None, help="instead: the sensitivity grid on these scenarios (a,b)")
    p.add_argument("--perturb", action="append", default=[], help="as `simharness sensitivity --perturb`")
    a = p.parse_args()
    if a.sensitivity:
        for sc in a.sensitivity.split(","):
            sensitivity_run(sc.strip(), a.predictors.split(",")[0], a.perturb or ["noise=0,1,2,4"],
                            a.seeds or parse_seeds("0-19"), a.workers, a.out)
        return 0
    scenarios = [s.strip() for s in a.scenarios.split(",") if s.strip()]
    seeds = a.seeds or list(range(1000 if a.until_resolved else 50))
    settings = SuiteSettings(predictors=tuple(a.predictors.split(",")), seeds=tuple(seeds),
                             until_resolved=a.until_resolved, target=a.target, budget_minutes=a.budget_minutes,
                             batch=a.batch, workers=a.workers)
    t0 = time.perf_counter()
    result = run_suite(stress_scenarios(scenarios), settings)
    wall = time.perf_counter() - t0
    paths = write_suite(a.out, result, "python bench/stress.py " + " ".join(sys.argv[1:]))
    print(paths["markdown"].read_text())
    info = result["info"]
    print(f"{info['episodes']} episodes, {info['seeds_per_scenario']} seeds x {len(scenarios)} scenarios, "
          f"{wall:.0f} s wall on {a.workers} workers ({info['stopped']}); cost per ego:")
    print(cost(result))
    for sc in scenarios:
        print(f"{sc:10} discriminating: {discriminates(result['scenarios'][sc])}")
    if a.open_loop_seeds:
        names = {n.strip(): n.strip() for n in a.open_loop_predictors.split(",") if n.strip()}
        print(f"Open loop (generated seeds {a.open_loop_seeds[0]}-{a.open_loop_seeds[-1]}, split all): ADE / FDE (m)")
        for sc in scenarios:
            ol = open_loop(sc, names, a.open_loop_seeds, a.workers, a.out)
            print(f"{sc:10} " + "  ".join(f"{n} {m['ade']:.2f}/{m['fde']:.2f}" for n, m in ol.items()))
    print(f"wrote {paths['markdown']}, {paths['json']}, {paths['figure']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
