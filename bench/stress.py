"""Stress-suite benchmark: every predictor on every `scenarios/stress/*.toml`, closed loop and open loop.

1. Closed loop: per (scenario, predictor) over the scored seeds (default 0-49; the scenarios were tuned
   on seeds 1000+): collision rate, at-fault collision rate, near misses per minute, progress, the
   composite score (where the loop computes one) and the online ADE, mean [95% bootstrap CI]; then,
   per scenario, whether it discriminates: oracle at-fault rate <= 0.02, static >= 0.30, constant
   velocity strictly between.
2. Open loop (--open-loop-seeds): data generated from each scenario (`simharness generate`, the ego on
   the simulator's own model) and each forecasting predictor scored on it (`simharness evaluate`,
   --split all): ADE/FDE beside the closed-loop ranks.

Each (scenario, predictor) result is kept under --out and reused on a rerun (delete it to remeasure).

    .venv/bin/python bench/stress.py --seeds 0-49 --predictors oracle,static,const-vel,traphic
    .venv/bin/python bench/stress.py --seeds 0-19 --predictors cs-lstm,none --open-loop-seeds 0-9
    .venv/bin/python bench/stress.py --seeds 0-9 --predictors traphic-b=runs/traphic-b  # a run folder, labelled
    .venv/bin/python bench/stress.py --out runs/o2 --scenarios brake --predictors oracle --seeds 10-29  # a chunk
    .venv/bin/python bench/stress.py --out runs/all --merge runs/o1,runs/o2 --scenarios brake --predictors oracle
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
from simharness.closedloop import EpisodeJob, aggregate, prepare_spec, run_episode  # noqa: E402
from simharness.scenario import SCENARIO_DIR, load_scenario  # noqa: E402

STRESS = sorted(p.stem for p in (SCENARIO_DIR / "stress").glob("*.toml"))
FIGURES = ("at_fault_collision_rate", "collision_rate", "composite", "near_misses_per_min", "progress_m",
           "online_ade")


def scores_of(job: EpisodeJob) -> dict:
    return run_episode(job)["scores"]


def run_jobs(jobs: list[EpisodeJob], workers: int, desc: str) -> list[dict]:
    """Episodes' scores through `workers` long-lived processes (the highway backend needs no fresh process per
    episode, unlike libsumo, so the project's executor's per-job start-up is skipped here), in job order."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    if workers <= 1:
        return [scores_of(j) for j in tqdm(jobs, desc=desc, file=sys.stderr)]
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
        return list(tqdm(pool.map(scores_of, jobs), total=len(jobs), desc=desc, file=sys.stderr))


def named(arg: str) -> dict[str, str]:
    """--predictors "a,b,LABEL=RUN" -> {label: predictor}: a run folder gets a label for the tables and cache."""
    pairs = [s.strip().split("=", 1) if "=" in s else [s.strip(), s.strip()] for s in arg.split(",") if s.strip()]
    return {k: v for k, v in pairs}


def closed_loop(scenario: str, predictor: str, seeds: list[int], workers: int, out: Path,
                cached_only: bool = False, label: str | None = None) -> dict | None:
    """Aggregate scores of one predictor on one stress scenario (cached in out/closedloop/ under label).

    cached_only: whatever is cached, on whichever seeds (None when nothing is)."""
    label = label or predictor
    path = out / "closedloop" / scenario / f"{label}.json"
    if path.is_file():
        cached = json.loads(path.read_text())
        if "composite" not in cached and any("composite" in e for e in cached["per_episode"]):
            from simharness.closedloop import bootstrap_ci

            cached["composite"] = bootstrap_ci([e.get("composite") for e in cached["per_episode"]])
        if cached["seeds"] == seeds or cached_only:
            return cached
    if cached_only:
        return None
    spec = prepare_spec(load_scenario(f"stress/{scenario}"))
    t0 = time.perf_counter()
    episodes = run_jobs([EpisodeJob(spec, s, predictor, keep_scene=False) for s in seeds], workers,
                        f"{scenario} {predictor}")
    agg = aggregate(episodes)
    keep = {k: agg[k] for k in FIGURES if k in agg}
    row = {"scenario": scenario, "predictor": label, "seeds": seeds, "episodes": len(episodes),
           "wall_s": round(time.perf_counter() - t0, 1), "mean_episode_wall_s": sum(e["wall_s"] for e in episodes)
           / max(len(episodes), 1), **keep,
           "per_episode": [{k: v for k, v in e.items() if not isinstance(v, dict)} for e in episodes]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(row, indent=1, default=float) + "\n")
    return row


PER_EPISODE = {"at_fault_collision_rate": "at_fault_collided", "collision_rate": "collided", "composite": "composite",
               "near_misses_per_min": "near_misses_per_min", "progress_m": "progress_m", "online_ade": "online_ade"}


def merge_runs(scenario: str, predictor: str, outs: list[Path], out: Path) -> dict | None:
    """Pool the cached episodes of one (scenario, predictor) from several --out folders (e.g. seed chunks run
    one after another) into out/closedloop/, with the bootstrap CIs recomputed over all of them."""
    from simharness.closedloop import bootstrap_ci

    parts = [json.loads(p.read_text()) for o in outs
             if (p := o / "closedloop" / scenario / f"{predictor}.json").is_file()]
    if not parts:
        return None
    parts.sort(key=lambda r: r["seeds"][0])
    eps = [e for r in parts for e in r["per_episode"]]
    present = [e for e in eps if e.get("ego_present", True)]
    row = {"scenario": scenario, "predictor": predictor, "seeds": [s for r in parts for s in r["seeds"]],
           "episodes": len(eps), "wall_s": sum(r["wall_s"] for r in parts),
           "mean_episode_wall_s": sum(e["wall_s"] for e in eps) / max(len(eps), 1),
           **{k: bootstrap_ci([e.get(v) for e in present]) for k, v in PER_EPISODE.items()}, "per_episode": eps}
    path = out / "closedloop" / scenario / f"{predictor}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(row, indent=1, default=float) + "\n")
    return row


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
    o, s, c = (rows[k]["at_fault_collision_rate"]["mean"] for k in need)
    ok = o <= 0.02 and s >= 0.30 and o < c < s
    return f"{'yes' if ok else 'NO'} (oracle {o:.2f}, const-vel {c:.2f}, static {s:.2f})"


def markdown(table: dict[str, dict[str, dict]], openloop: dict[str, dict[str, dict]], seeds: list[int]) -> str:
    """The suite as Markdown: per scenario the closed-loop figures, then the leaderboard with open-loop ranks."""
    score = "composite" if any("composite" in r for rows in table.values() for r in rows.values()) \
        else None
    lines = ["Closed loop: mean [95% bootstrap CI] over the seeds of each row.", "",
             "| scenario | predictor | seeds | at-fault collision rate | collision rate | composite score "
             "| near misses / min "
             "| progress (m) | online ADE (m) | s / episode |", "|" + "---|" * 10]
    for sc, rows in table.items():
        for name, r in rows.items():
            seeds_txt = f"{r['seeds'][0]}-{r['seeds'][-1]}"
            lines.append(f"| {sc} | {name} | {seeds_txt} | {fmt(r.get('at_fault_collision_rate'))} "
                         f"| {fmt(r.get('collision_rate'))} "
                         f"| {fmt(r.get('composite'))} | {fmt(r.get('near_misses_per_min'))} "
                         f"| {fmt(r.get('progress_m'))} | {fmt(r.get('online_ade'))} "
                         f"| {r['mean_episode_wall_s']:.1f} |")
    lines += ["", "| scenario | discriminating (at-fault rate: oracle <= 0.02, static >= 0.30, const-vel between) |",
              "|---|---|"]
    lines += [f"| {sc} | {discriminates(rows)} |" for sc, rows in table.items()]
    if openloop:
        key = score or "at_fault_collision_rate"
        lines += ["", f"Open-loop ADE / FDE (m) on data generated from each scenario beside the closed-loop "
                  f"{'composite score (higher is better)' if score else 'at-fault rate (lower is better)'}; "
                  "ranks among the forecasting predictors.", "",
                  "| scenario | predictor | open-loop ADE / FDE | open-loop rank | closed-loop "
                  f"{'score' if score else 'at-fault rate'} | closed-loop rank |", "|---|---|---|---|---|---|"]
        for sc, ol in openloop.items():
            names = [n for n in ol if n in table[sc]]
            sign = -1 if score else 1
            names = [n for n in names if key in table[sc][n]]
            cl_rank = {n: i + 1 for i, n in enumerate(sorted(names, key=lambda n: sign * table[sc][n][key]["mean"]))}
            ol_rank = {n: i + 1 for i, n in enumerate(sorted(names, key=lambda n: ol[n]["ade"]))}
            for n in names:
                lines.append(f"| {sc} | {n} | {ol[n]['ade']:.2f} / {ol[n]['fde']:.2f} | {ol_rank[n]} "
                             f"| {fmt(table[sc][n][key])} | {cl_rank[n]} |")
    return "\n".join(lines) + "\n"


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
    p.add_argument("--predictors", default="oracle,static,const-vel,traphic",
                   help="names, or LABEL=RUN for a `simharness train` run folder")
    p.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0-49"))
    p.add_argument("--open-loop-seeds", type=parse_seeds, default=None, help="also score open loop on these seeds")
    p.add_argument("--open-loop-predictors", default="traphic,cs-lstm,const-vel", help="as --predictors")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/bench_stress"))
    p.add_argument("--report", action="store_true", help="only tabulate what is cached under --out (any seeds)")
    p.add_argument("--merge", default=None, help="first pool the cached episodes of these --out folders (a,b; "
                   "e.g. seed chunks of a slow predictor) into --out, then tabulate as --report")
    p.add_argument("--sensitivity", default=None, help="instead: the sensitivity grid on these scenarios (a,b)")
    p.add_argument("--perturb", action="append", default=[], help="as `simharness sensitivity --perturb`")
    a = p.parse_args()
    if a.sensitivity:
        for sc in a.sensitivity.split(","):
            sensitivity_run(sc.strip(), a.predictors.split(",")[0], a.perturb or ["noise=0,1,2,4"], a.seeds,
                            a.workers, a.out)
        return 0
    scenarios = [s.strip() for s in a.scenarios.split(",") if s.strip()]
    predictors = named(a.predictors)
    table: dict[str, dict[str, dict]] = {}
    if a.merge:
        for sc in scenarios:
            for name in predictors:
                merge_runs(sc, name, [Path(o.strip()) for o in a.merge.split(",")], a.out)
        a.report = True
    for sc in scenarios:
        rows = {name: closed_loop(sc, spec, a.seeds, a.workers, a.out, a.report, name)
                for name, spec in predictors.items()}
        table[sc] = {k: v for k, v in rows.items() if v is not None}
    print(f"Closed loop, seeds {a.seeds[0]}-{a.seeds[-1]} ({len(a.seeds)}): mean [95% bootstrap CI]")
    print(f"{'scenario':10} {'predictor':10} {'at-fault rate':>20} {'collision rate':>20} {'composite':>20} "
          f"{'near miss/min':>20} {'online ADE':>20} {'s/episode':>9}")
    for sc, rows in table.items():
        for name, r in rows.items():
            print(f"{sc:10} {name:10} {fmt(r.get('at_fault_collision_rate')):>20} {fmt(r.get('collision_rate')):>20} "
                  f"{fmt(r.get('composite')):>20} {fmt(r.get('near_misses_per_min')):>20} "
                  f"{fmt(r.get('online_ade')):>20} {r['mean_episode_wall_s']:9.1f}")
        print(f"{sc:10} discriminating: {discriminates(rows)}")
    openloop: dict[str, dict[str, dict]] = {}
    if a.open_loop_seeds:
        names = named(a.open_loop_predictors)
        print(f"Open loop (generated seeds {a.open_loop_seeds[0]}-{a.open_loop_seeds[-1]}, split all): ADE / FDE (m)")
        for sc in scenarios:
            openloop[sc] = open_loop(sc, names, a.open_loop_seeds, a.workers, a.out)
            print(f"{sc:10} " + "  ".join(f"{n} {m['ade']:.2f}/{m['fde']:.2f}" for n, m in openloop[sc].items()))
    (a.out / "stress.md").write_text(markdown(table, openloop, a.seeds))
    print(f"wrote {a.out / 'stress.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
