"""`simharness sensitivity`: the closed loop over a grid of forecast perturbations -> table + figure.

Every (perturbation, seed) is one closed-loop episode of one predictor (usually the oracle) whose
forecasts a `PerturbedPredictor` degrades; all go through one executor run. Per perturbation: the
measured online ADE of the degraded forecasts and the closed-loop figures (collision rate, at-fault
collision rate, near misses per ego-minute, progress, the composite score where the loop computes
one), each a mean with a 95% percentile-bootstrap CI over seeds. What a metre of prediction error
costs in safety is then the slope of the at-fault rate against the online ADE.

Outputs in `--out`: sensitivity.json (settings, seeds, rows, every episode's scores),
sensitivity.md (the table) and sensitivity.png (each figure against the online ADE).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from simharness.closedloop.aggregation import bootstrap_ci
from simharness.closedloop.config import EpisodeJob, LoopConfig
from simharness.closedloop.episode import REFERENCE_EGOS, prepare_spec, raise_user_error, run_episode
from simharness.closedloop.perturbations import Perturbation, parse_grid
from simharness.errors import SimulatorError, UserError
from simharness.io.folders import prepare_output
from simharness.scenario import ScenarioSpec, load_scenario

# (row key, per-episode score it averages, label); keys the loop does not compute are left out
METRICS = (("online_ade", "online_ade", "online ADE (m)"), ("online_fde", "online_fde", "online FDE (m)"),
           ("collision_rate", "collided", "collision rate"),
           ("at_fault_collision_rate", "at_fault_collided", "at-fault collision rate"),
           ("near_misses_per_min", "near_misses_per_min", "near misses / min"),
           ("progress_m", "progress_m", "progress (m)"), ("composite", "composite", "composite score"))


def run_scores(job: EpisodeJob) -> dict[str, Any]:
    """The job function: one episode -> its scores only."""
    return run_episode(job)["scores"]


def sensitivity(spec: ScenarioSpec, predictor: str, grid: Sequence[Perturbation], seeds: Sequence[int], out: Path,
                workers: int = 2, executor: str = "local", address: str | None = None,
                config: LoopConfig | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the grid and write sensitivity.{json,md,png} under `out`; returns what the JSON holds.

    {"info": {...}, "rows": [{perturbation, params, episodes, <metric>: {mean, lo, hi, n}}],
     "monotone": {metric: bool}, "episodes": [...]}.
    """
    from tqdm import tqdm

    from simharness.executors import make_executor

    config = config or LoopConfig()
    if predictor in ("none", "blind"):
        raise UserError(f"--predictor {predictor}: drives without forecasts, so there is nothing to perturb")
    if predictor not in REFERENCE_EGOS:
        from simharness.plugins import check_predictor

        check_predictor(predictor, REFERENCE_EGOS)  # a bad name fails now, before any process starts
    jobs = sensitivity_jobs(spec, predictor, grid, seeds, config)
    t0 = time.perf_counter()
    scores: dict[str, list[dict[str, Any]]] = {p.label(): [] for p in grid}
    failed: list[str] = []
    bar = tqdm(total=len(jobs), desc=f"sensitivity {spec.name} {predictor}", unit="ep", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    try:
        for r in make_executor(executor, workers, address).map_unordered(run_scores, jobs):
            label = r.job.perturbation.label()
            if r.ok:
                scores[label].append(r.value)
            else:
                raise_user_error(r.error)  # bad input (an invalid forecast) is one line, not a failed episode
                failed.append(f"{label} seed {r.job.seed}: {r.error}")
            bar.update(1)
            bar.set_postfix_str(label)
    finally:
        bar.close()
    if failed:  # a figure over a silent subset of seeds would mislead
        raise SimulatorError(f"{len(failed)} episode(s) failed: " + "; ".join(failed[:3]))
    result = summarise(prepare_spec(spec), predictor, grid, seeds, config, scores, time.perf_counter() - t0)
    write_outputs(Path(out), result)
    return result


def sensitivity_jobs(spec: ScenarioSpec, predictor: str, grid: Sequence[Perturbation], seeds: Sequence[int],
                     config: LoopConfig | None = None) -> list[EpisodeJob]:
    """One episode job per (perturbation, seed), perturbation-major."""
    spec = prepare_spec(spec)
    if seeds:  # the seed the simulator gets stays 32-bit, or one line before any work
        spec.sim_seed(max(seeds))
    return [EpisodeJob(spec, int(s), predictor, config or LoopConfig(), keep_scene=False, perturbation=p)
            for p in grid for s in seeds]


def summarise(spec: ScenarioSpec, predictor: str, grid: Sequence[Perturbation], seeds: Sequence[int],
              config: LoopConfig, scores: dict[str, list[dict[str, Any]]], seconds: float) -> dict[str, Any]:
    """Rows of CIs per perturbation from the episodes' scores ({label: [scores]}); what sensitivity.json holds."""
    from simharness.io.parquet import software_versions

    rows = []
    for p in grid:
        eps = [e for e in sorted(scores[p.label()], key=lambda e: e["seed"]) if e.get("ego_present")]
        row: dict[str, Any] = {"perturbation": p.label(), "params": dataclasses.asdict(p), "episodes": len(eps)}
        row.update({name: bootstrap_ci([e.get(key) for e in eps]) for name, key, _ in METRICS
                    if any(key in e for e in eps)})
        rows.append(row)
    info = {"scenario": spec.name, "config_hash": spec.config_hash(), "predictor": predictor,
            "seeds": [int(s) for s in seeds], "grid": [p.label() for p in grid], "loop": dataclasses.asdict(config),
            "seconds": round(seconds, 3), "command": sys.argv, "versions": software_versions(),
            "bootstrap": {"resamples": 2000, "level": 0.95, "seed": 0}}
    result = {"info": info, "rows": rows, "monotone": {k: monotone(rows, k) for k in
                                                       ("collision_rate", "at_fault_collision_rate")},
              "episodes": [{"perturbation": p.label(), **e} for p in grid
                           for e in sorted(scores[p.label()], key=lambda e: e["seed"])]}
    return result


def monotone(rows: Sequence[dict[str, Any]], key: str) -> bool:
    """Rows in order of growing error: does `key` never fall below the previous row's CI (rises within CIs)?"""
    cis = [r[key] for r in rows if key in r and r[key]["n"]]
    return all(b["mean"] >= a["lo"] - 1e-12 for a, b in zip(cis, cis[1:], strict=False))


def _ci(ci: dict[str, Any] | None, digits: int = 2) -> str:
    if not ci or not ci.get("n") or not math.isfinite(ci["mean"]):
        return "n/a"
    return f"{ci['mean']:.{digits}f} [{ci['lo']:.{digits}f}, {ci['hi']:.{digits}f}]"


def markdown_table(result: dict[str, Any]) -> str:
    """One row per perturbation: mean [95% bootstrap CI] of each metric."""
    present = [(k, label) for k, _, label in METRICS if any(k in r for r in result["rows"])]
    head = ["perturbation", "episodes", *(label for _, label in present)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in result["rows"]:
        lines.append("| " + " | ".join([r["perturbation"], str(r["episodes"]), *(_ci(r.get(k)) for k, _ in present)])
                     + " |")
    return "\n".join(lines)


def plot(result: dict[str, Any], path: Path) -> None:
    """Each closed-loop figure against the measured online ADE, with 95% CIs both ways (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    panels = [(k, label) for k, _, label in METRICS if k not in ("online_ade", "online_fde")
              and any(k in r for r in rows)]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 3.2), squeeze=False)
    x = [r["online_ade"] for r in rows]
    for ax, (key, label) in zip(axes[0], panels, strict=True):
        y = [r.get(key) or {"mean": math.nan, "lo": math.nan, "hi": math.nan} for r in rows]
        ax.errorbar([a["mean"] for a in x], [b["mean"] for b in y],
                    xerr=[[a["mean"] - a["lo"] for a in x], [a["hi"] - a["mean"] for a in x]],
                    yerr=[[b["mean"] - b["lo"] for b in y], [b["hi"] - b["mean"] for b in y]],
                    marker="o", capsize=3)
        for a, b, r in zip(x, y, rows, strict=True):
            ax.annotate(r["perturbation"], (a["mean"], b["mean"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xlabel("online ADE (m)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    info = result["info"]
    fig.suptitle(f"{info['scenario']}, {info['predictor']}: {len(info['seeds'])} seeds per point, "
                 "mean and 95% bootstrap CI", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def write_outputs(out: Path, result: dict[str, Any]) -> None:
    """sensitivity.json, sensitivity.md, sensitivity.png, each written whole."""
    from simharness.io.parquet import atomic_write_bytes, dumps

    out.mkdir(parents=True, exist_ok=True)
    plot(result, out / "sensitivity.png")
    info = result["info"]
    mono = ", ".join(f"{k}: {'yes' if v else 'no'}" for k, v in result["monotone"].items())
    text = (f"# Sensitivity of {info['scenario']} to {info['predictor']}'s forecast errors "
            f"(config {info['config_hash']})\n\nSeeds {info['seeds'][0]}-{info['seeds'][-1]} "
            f"({len(info['seeds'])}); mean [95% percentile-bootstrap CI] over episodes. Rises monotonically "
            f"within CIs: {mono}.\n\n" + markdown_table(result) + "\n\n![sensitivity](sensitivity.png)\n")
    atomic_write_bytes(out / "sensitivity.md", text.encode())
    atomic_write_bytes(out / "sensitivity.json", (dumps(result, indent=1) + "\n").encode())


def sensitivity_command(args: Any) -> int:
    """`simharness sensitivity SCENARIO --predictor oracle --perturb noise=0,1,2 --seeds 0-49 --out DIR`."""
    spec = load_scenario(args.scenario)
    grid = parse_grid(args.perturb or ["noise=0"])
    prepare_output(Path(args.out), getattr(args, "force", False))
    result = sensitivity(spec, args.predictor, grid, args.seeds, Path(args.out), args.workers, args.executor,
                         args.address)
    print(markdown_table(result))
    out = Path(args.out)
    print(f"wrote {out / 'sensitivity.md'}, {out / 'sensitivity.json'}, {out / 'sensitivity.png'} "
          f"({result['info']['seconds']:.1f} s)")
    return 0
