"""`simharness stress`: every scenario of scenarios/stress/ with every named ego on the same seeds -> the
leaderboard (Markdown, strict JSON, a PNG figure) with paired verdicts against a baseline (constant velocity).

Per scenario and pooled over the suite (each scenario weighing the same): the at-fault collision rate, the
collision rate, the composite score, the near-miss rate, the online ADE and the forecast coverage, each a mean
with a 95% percentile-bootstrap CI (stratified by scenario when pooled). Every prediction-driven ego is then
compared with the baseline seed by seed (`paired`): the paired difference with its 95% CI and a plain verdict.
'none' (the simulator's own driver, no prediction) is reported apart, as a reference. Planners named in
`planners` (a learned policy such as 'ppo', a policy .zip, a plug-in) are egos too: each drives instead of the
prediction-driven planner, fed constant-velocity forecasts where it reads any, and is paired with the baseline
like the prediction-driven egos.

With `until_resolved` the seeds are run in batches until the pooled at-fault difference of the `resolve` ego
minus the baseline has a CI half-width <= `target` (with at least `MIN_RESOLVE_SEEDS` seeds per scenario), the
next batch would overrun the time budget, or the seeds run out. Every (scenario, ego, seed) of a batch is one
job of one executor run.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simharness.closedloop.aggregation import strict_dumps
from simharness.closedloop.config import EpisodeJob, LoopConfig
from simharness.closedloop.episode import REFERENCE_EGOS, _predictor, prepare_spec, raise_user_error, run_episode
from simharness.closedloop.paired import paired_difference, paired_values, stratified_ci, verdict
from simharness.errors import SimulatorError, UserError
from simharness.scenario import SCENARIO_DIR, ScenarioSpec, load_scenario

STRESS_DIR = SCENARIO_DIR / "stress"
BASELINE = "const-vel"
DRIVERS = ("none", "blind")  # egos that use no forecast: reported apart, as references
METRICS = (("at_fault_collided", "at-fault rate"), ("collided", "collision rate"), ("composite", "composite"),
           ("near_miss", "near-miss rate"), ("online_ade", "online ADE (m)"),
           ("forecast_coverage", "coverage"))
COMPARED = ("at_fault_collided", "collided", "composite")  # paired against the baseline
MIN_RESOLVE_SEEDS = 30  # per scenario: fewer, and an all-zero difference would read as resolved


@dataclasses.dataclass(frozen=True)
class SuiteSettings:
    """What `run_suite` runs: egos by name, the baseline they are paired against and the seeds' schedule."""

    predictors: tuple[str, ...]
    seeds: tuple[int, ...]
    baseline: str = BASELINE
    until_resolved: bool = False
    resolve: str | None = None  # the ego whose pooled at-fault difference from the baseline must be resolved
    target: float = 0.03  # CI half-width
    budget_minutes: float = 30.0
    batch: int = 20  # seeds per batch with until_resolved
    workers: int = 2
    executor: str = "local"
    address: str | None = None
    planners: tuple[str, ...] = ()  # planner egos (learned policies, plug-ins), labelled by name


def stress_scenarios(names: Sequence[str] | None = None, duration: float | None = None) -> list[ScenarioSpec]:
    """The suite's scenarios with their ego enabled: every scenarios/stress/*.toml, or those named (a stress
    scenario's name or any scenario file); `duration` (s) overrides each one's."""
    names = list(names) if names else sorted(p.stem for p in STRESS_DIR.glob("*.toml"))
    if not names:
        raise UserError(f"{STRESS_DIR}: no stress scenarios (*.toml) found")
    specs = []
    for n in names:
        spec = load_scenario(f"stress/{n}" if (STRESS_DIR / f"{n}.toml").is_file() else n)
        if duration is not None:
            spec = spec.with_overrides({"duration": float(duration)})
        specs.append(prepare_spec(spec))
    if len({s.name for s in specs}) != len(specs):
        raise UserError("--scenarios: two scenarios share a name; give each file its own `name`")
    return specs


def egos_of(predictors: Sequence[str], baseline: str) -> tuple[str, ...]:
    """The egos to run: the named ones (deduplicated, in order) and the baseline, which every other is paired with."""
    names = list(dict.fromkeys(p.strip() for p in predictors if p.strip()))
    if not names:
        raise UserError("--predictor: expected names, e.g. oracle,traphic,const-vel,static,none")
    return tuple(names if baseline in names else [*names, baseline])


def default_resolve(egos: Sequence[str], baseline: str) -> str | None:
    """The ego whose difference from the baseline `until_resolved` resolves: traphic when run, else the first
    prediction-driven ego that is neither the baseline nor a reference (oracle, static)."""
    if "traphic" in egos and baseline != "traphic":
        return "traphic"
    return next((e for e in egos if e != baseline and e not in REFERENCE_EGOS), None)


PLANNER_FORECASTS = BASELINE  # the forecasts a planner ego is fed (a policy that reads none ignores them)


def ego_job(spec: ScenarioSpec, seed: int, ego: str, planners: Sequence[str], config: LoopConfig) -> EpisodeJob:
    """The episode of `ego` on `seed`: a prediction-driven ego (the default planner, its forecasts) or, for a name
    in `planners`, that planner driving on constant-velocity forecasts."""
    if ego in planners:
        return EpisodeJob(spec, seed, PLANNER_FORECASTS, config, keep_scene=False, planner=ego)
    return EpisodeJob(spec, seed, ego, config, keep_scene=False)


def ego_of(job: EpisodeJob) -> str:
    """The ego label of a job (`ego_job`'s inverse)."""
    return job.planner if job.planner != "pdm" else job.predictor


def episode_scores(job: EpisodeJob) -> dict[str, Any]:
    """The job function: one episode -> its scalar scores (and seed, ego, timings)."""
    return {k: v for k, v in run_episode(job)["scores"].items() if not isinstance(v, dict)}


def run_batch(specs: Sequence[ScenarioSpec], egos: Sequence[str], seeds: Sequence[int], settings: SuiteSettings,
              config: LoopConfig, progress: bool = True) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """Every (scenario, ego, seed) through one executor run -> {scenario: {ego: [scores, by seed]}}.

    A UserError in a worker (an invalid forecast) stops the run as that one line; other failures raise
    SimulatorError naming them after the batch.
    """
    from tqdm import tqdm

    from simharness.executors import make_executor

    jobs = [ego_job(spec, s, ego, settings.planners, config) for s in seeds for spec in specs for ego in egos]
    out: dict[str, dict[str, list[dict[str, Any]]]] = {sp.name: {e: [] for e in egos} for sp in specs}
    failed = []
    bar = tqdm(total=len(jobs), desc=f"stress seeds {seeds[0]}-{seeds[-1]}", unit="ep", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    try:
        for r in make_executor(settings.executor, settings.workers, settings.address).map_unordered(
                episode_scores, jobs):
            bar.update(1)
            if r.ok:
                out[r.job.spec.name][ego_of(r.job)].append(r.value)
            else:
                raise_user_error(r.error)
                failed.append(f"{r.job.spec.name} {ego_of(r.job)} seed {r.job.seed}: {r.error}")
    finally:
        bar.close()
    if failed:
        raise SimulatorError(f"{len(failed)} stress episode(s) failed: " + "; ".join(failed[:3]))
    for rows in out.values():
        for eps in rows.values():
            eps.sort(key=lambda e: e["seed"])
    return out


def paired_against(episodes: dict[str, dict[str, list[dict[str, Any]]]], ego: str, baseline: str, key: str,
                   seed: int = 0) -> dict[str, Any]:
    """`ego` minus `baseline` on per-episode `key`, paired on seed: per scenario and pooled (stratified), each
    {"mean", "lo", "hi", "half_width", "n", "verdict"}."""
    per = {sc: paired_values(rows[ego], rows[baseline], key)[1:] for sc, rows in episodes.items()}
    scen = {sc: paired_difference([a], [b], seed=seed) for sc, (a, b) in per.items()}
    pooled = paired_difference([a for a, _ in per.values()], [b for _, b in per.values()], seed=seed)
    for d in (*scen.values(), pooled):
        d["verdict"] = verdict(ego, baseline, d, key)
    return {"pooled": pooled, "scenarios": scen}


def leaderboard(episodes: dict[str, dict[str, list[dict[str, Any]]]], egos: Sequence[str], baseline: str,
                seed: int = 0) -> dict[str, Any]:
    """The leaderboard of a suite run from its episodes ({scenario: {ego: [scores]}}):

    {"scenarios": {sc: {ego: {"episodes", key: ci}}}, "pooled": {ego: {key: ci}},
     "paired": {ego: {key: paired_against(...)}}} for key in METRICS / COMPARED; ci as `paired.stratified_ci`.
    """
    def values(eps: list[dict[str, Any]], key: str) -> np.ndarray:
        return np.array([np.nan if e.get(key) is None else e[key] for e in eps if e.get("ego_present")], np.float64)

    scenarios = {sc: {e: {"episodes": len(rows[e]), **{k: stratified_ci([values(rows[e], k)], seed=seed)
                                                       for k, _ in METRICS}} for e in egos}
                 for sc, rows in episodes.items()}
    pooled = {e: {"episodes": sum(len(rows[e]) for rows in episodes.values()),
                  **{k: stratified_ci([values(rows[e], k) for rows in episodes.values()], seed=seed)
                     for k, _ in METRICS}} for e in egos}
    paired = {e: {k: paired_against(episodes, e, baseline, k, seed) for k in COMPARED} for e in egos if e != baseline}
    return {"scenarios": scenarios, "pooled": pooled, "paired": paired}


def run_suite(specs: Sequence[ScenarioSpec], settings: SuiteSettings, config: LoopConfig | None = None,
              progress: bool = True) -> dict[str, Any]:
    """Run the suite (in batches with `until_resolved`) -> {"info", "scenarios", "pooled", "paired", "episodes"}."""
    config = config or LoopConfig()
    egos = egos_of(settings.predictors, settings.baseline)
    if clash := set(egos) & set(settings.planners):
        raise UserError(f"--planner {', '.join(sorted(clash))}: also named in --predictor; an ego needs one name")
    for e in egos:
        if e not in REFERENCE_EGOS:
            _predictor(e)  # a bad name fails now, before any process starts
    if settings.planners:
        from simharness.plugins import check_planner

        for p in settings.planners:
            check_planner(p, specs[0])
        egos = (*egos, *settings.planners)
    resolve = settings.resolve or default_resolve(egos, settings.baseline)
    if settings.until_resolved and (resolve is None or resolve not in egos or resolve == settings.baseline):
        raise UserError(f"--resolve: expected one of the egos run other than the baseline {settings.baseline!r} "
                        f"({', '.join(egos)}), got {resolve!r}")
    seeds = list(settings.seeds)
    batch = settings.batch if settings.until_resolved else len(seeds)
    episodes: dict[str, dict[str, list[dict[str, Any]]]] = {sp.name: {e: [] for e in egos} for sp in specs}
    t0, done, history, stop = time.perf_counter(), [], [], "seeds run"
    while len(done) < len(seeds):
        chunk = seeds[len(done): len(done) + batch]
        t1 = time.perf_counter()
        for sc, rows in run_batch(specs, egos, chunk, settings, config, progress).items():
            for e, eps in rows.items():
                episodes[sc][e].extend(eps)
        done += chunk
        now = time.perf_counter()
        if resolve is None:
            continue
        d = paired_against(episodes, resolve, settings.baseline, "at_fault_collided")["pooled"]
        history.append({"seeds": len(done), "wall_s": round(now - t0, 1), "mean": d["mean"],
                        "half_width": d["half_width"]})
        if progress:
            print(f"{len(done)} seeds x {len(specs)} scenarios, {now - t0:.0f} s: {resolve} minus "
                  f"{settings.baseline} pooled at-fault rate {d['mean']:+.3f} +- {d['half_width']:.3f}",
                  file=sys.stderr)
        if not settings.until_resolved:
            continue
        if len(done) >= MIN_RESOLVE_SEEDS and d["half_width"] <= settings.target:
            stop = "resolved"
            break
        if now - t0 + (now - t1) * min(batch, len(seeds) - len(done)) / len(chunk) > 60 * settings.budget_minutes:
            stop = "budget spent"
            break
    wall = time.perf_counter() - t0
    board = leaderboard(episodes, egos, settings.baseline)
    cpu = {e: sum(ep.get("cpu_s", 0.0) for rows in episodes.values() for ep in rows[e]) for e in egos}
    n_ep = {e: sum(len(rows[e]) for rows in episodes.values()) for e in egos}
    info = {"scenarios": [s.name for s in specs], "egos": list(egos), "baseline": settings.baseline,
            "references": [e for e in egos if e in DRIVERS], "seeds": done, "seeds_per_scenario": len(done),
            "until_resolved": settings.until_resolved, "resolve": resolve, "target_half_width": settings.target,
            "budget_minutes": settings.budget_minutes, "stopped": stop, "batches": history,
            "wall_s": round(wall, 1), "workers": settings.workers, "episodes": sum(n_ep.values()),
            "episodes_per_cpu_minute": {e: n_ep[e] / (cpu[e] / 60.0) if cpu[e] > 0 else None for e in egos},
            "scenario_hashes": {s.name: s.config_hash() for s in specs},
            "loop": dataclasses.asdict(config)}
    return {"info": info, **board, "episodes": episodes}


# ---------------------------------------------------------------------- writing
def _ci(d: dict[str, Any] | None, digits: int = 2) -> str:
    if not d or d.get("mean") is None or not np.isfinite(d["mean"]):
        return "n/a"
    return f"{d['mean']:.{digits}f} [{d['lo']:.{digits}f}, {d['hi']:.{digits}f}]"


def _diff(d: dict[str, Any]) -> str:
    if not d.get("n"):
        return "n/a"
    return f"{d['mean']:+.3f} [{d['lo']:+.3f}, {d['hi']:+.3f}]"


def leaderboard_markdown(result: dict[str, Any], command: str = "") -> str:
    """The leaderboard as Markdown: the verdicts, pooled figures, paired differences, then each scenario."""
    info, base = result["info"], result["info"]["baseline"]
    egos = [e for e in info["egos"] if e not in DRIVERS]
    refs = [e for e in info["egos"] if e in DRIVERS]
    n = info["seeds_per_scenario"]
    seeds = info["seeds"]
    lines = ["# Stress suite leaderboard", "",
             f"{len(info['scenarios'])} scenarios ({', '.join(info['scenarios'])}), {n} seeds each "
             f"({seeds[0]}-{seeds[-1]}" + (")" if len(seeds) == seeds[-1] - seeds[0] + 1 else ", not contiguous)")
             + f", the same seeds for every ego (paired); {info['episodes']} episodes in {info['wall_s']:.0f} s "
             f"on {info['workers']} worker(s). Mean [95% bootstrap CI]; pooled: each scenario weighs the same, "
             "resampled within scenarios.", ""]
    if command:
        lines += ["Reproduce: `" + command + "`", ""]
    if info["until_resolved"]:
        lines += [f"Seeds were added in batches until {info['resolve']} minus {base}, pooled at-fault rate, had a "
                  f"95% CI half-width <= {info['target_half_width']} or {info['budget_minutes']:g} minutes were "
                  f"spent: stopped ({info['stopped']}).", ""]
    lines += [f"## Verdicts against {base} (pooled, paired on seeds)", ""]
    for e in egos + refs:
        if e == base:
            continue
        p = result["paired"][e]
        lines.append(f"- {e}: at-fault {_diff(p['at_fault_collided']['pooled'])}: "
                     f"{p['at_fault_collided']['pooled']['verdict']}; composite {_diff(p['composite']['pooled'])}: "
                     f"{p['composite']['pooled']['verdict']}" + (" (reference: the simulator's driver)"
                                                                  if e in refs else ""))
    head = "| ego | episodes | " + " | ".join(label for _, label in METRICS) + " |"
    rule = "|---" * (len(METRICS) + 2) + "|"

    def row(name: str, r: dict[str, Any]) -> str:
        return (f"| {name} | {r['episodes']} | "
                + " | ".join(_ci(r[k], 3 if k == "forecast_coverage" else 2) for k, _ in METRICS) + " |")

    lines += ["", "## Pooled over the suite", "", head, rule]
    lines += [row(e, result["pooled"][e]) for e in egos]
    if refs:
        lines += ["", "Reference (the simulator's own driver, no prediction):", "", head, rule]
        lines += [row(e, result["pooled"][e]) for e in refs]
    lines += ["", f"## Paired differences, ego minus {base}", "",
              "| ego | scenario | at-fault rate | collision rate | composite | verdict (at-fault) |",
              "|---|---|---|---|---|---|"]
    for e in egos + refs:
        if e == base:
            continue
        p = result["paired"][e]
        for sc in ["pooled", *info["scenarios"]]:
            d = {k: p[k]["pooled"] if sc == "pooled" else p[k]["scenarios"][sc] for k in COMPARED}
            lines.append(f"| {e} | {sc} | {_diff(d['at_fault_collided'])} | {_diff(d['collided'])} "
                         f"| {_diff(d['composite'])} | {d['at_fault_collided']['verdict']} |")
    for sc in info["scenarios"]:
        rows = result["scenarios"][sc]
        lines += ["", f"## {sc}", "", head, rule]
        lines += [row(e, rows[e]) for e in egos]
        lines += [row(f"{e} (reference)", rows[e]) for e in refs]
    rates = info["episodes_per_cpu_minute"]
    lines += ["", "Episodes per CPU-minute (process time of the episode's worker): "
              + ", ".join(f"{e} {rates[e]:.1f}" for e in info["egos"] if rates.get(e)), ""]
    return "\n".join(lines)


def plot_leaderboard(result: dict[str, Any], path: Path) -> Path:
    """The leaderboard as a figure: at-fault rate and composite per scenario and pooled (one marker per ego, with
    its 95% CI), and each ego's pooled paired at-fault difference from the baseline -> PNG."""
    from simharness.report import _save, plt

    info = result["info"]
    egos = info["egos"]
    cols = [*info["scenarios"], "pooled"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.8), dpi=110)
    width = 0.8 / max(len(egos), 1)
    for ax, key, label in ((axes[0], "at_fault_collided", "at-fault collision rate"),
                           (axes[1], "composite", "composite score")):
        for i, e in enumerate(egos):
            cis = [result["pooled"][e][key] if c == "pooled" else result["scenarios"][c][e][key] for c in cols]
            m = np.array([np.nan if d["mean"] is None else d["mean"] for d in cis], float)
            lo = np.array([np.nan if d["lo"] is None else d["lo"] for d in cis], float)
            hi = np.array([np.nan if d["hi"] is None else d["hi"] for d in cis], float)
            x = np.arange(len(cols)) + (i - (len(egos) - 1) / 2) * width
            ax.errorbar(x, m, yerr=[m - lo, hi - m], fmt="o", ms=4, capsize=2, label=e)
        ax.set_xticks(np.arange(len(cols)), cols, rotation=20, fontsize=8)
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3, axis="y")
    axes[0].legend(fontsize=7)
    others = [e for e in egos if e != info["baseline"]]
    d = [result["paired"][e]["at_fault_collided"]["pooled"] for e in others]
    m = np.array([np.nan if x["mean"] is None else x["mean"] for x in d], float)
    lo = np.array([np.nan if x["lo"] is None else x["lo"] for x in d], float)
    hi = np.array([np.nan if x["hi"] is None else x["hi"] for x in d], float)
    y = np.arange(len(others))
    axes[2].errorbar(m, y, xerr=[m - lo, hi - m], fmt="o", capsize=3, color="black")
    axes[2].axvline(0.0, color="grey", lw=1)
    axes[2].set_yticks(y, others, fontsize=8)
    axes[2].set_title(f"at-fault rate minus {info['baseline']}'s (pooled, paired, 95% CI)", fontsize=9)
    return _save(fig, Path(path))


def write_suite(out: Path, result: dict[str, Any], command: str = "") -> dict[str, Path]:
    """leaderboard.md, leaderboard.json (strict JSON: every episode's scores too) and leaderboard.png in `out`."""
    from simharness.io.parquet import atomic_write_bytes, software_versions

    out.mkdir(parents=True, exist_ok=True)
    result = {**result, "info": {**result["info"], "command": command, "versions": software_versions()}}
    paths = {"markdown": out / "leaderboard.md", "json": out / "leaderboard.json"}
    atomic_write_bytes(paths["markdown"], leaderboard_markdown(result, command).encode())
    atomic_write_bytes(paths["json"], (strict_dumps(result) + "\n").encode())
    paths["figure"] = plot_leaderboard(result, out / "leaderboard.png")
    return paths


def stress_command(args: Any) -> int:
    """`simharness stress --predictor A,B,... [--seeds RANGE | --until-resolved --budget-minutes M] [--out DIR]`."""
    from simharness.io.folders import prepare_output

    until = bool(args.until_resolved)
    seeds = args.seeds if args.seeds is not None else list(range(0, 1000 if until else 50))
    if args.batch < 1:
        raise UserError(f"--batch: expected a positive number of seeds, got {args.batch}")
    if args.target <= 0 or args.budget_minutes <= 0:
        raise UserError("--target and --budget-minutes: expected positive numbers")
    settings = SuiteSettings(predictors=tuple(str(args.predictor).split(",")), seeds=tuple(seeds),
                             baseline=args.baseline, until_resolved=until, resolve=args.resolve, target=args.target,
                             budget_minutes=args.budget_minutes, batch=args.batch, workers=args.workers,
                             executor=args.executor, address=args.address,
                             planners=tuple(p.strip() for p in str(args.planner or "").split(",") if p.strip()))
    scenarios = [s.strip() for s in args.scenarios.split(",") if s.strip()] if args.scenarios else None
    specs = stress_scenarios(scenarios, args.duration)
    out = prepare_output(Path(args.out), getattr(args, "force", False))
    result = run_suite(specs, settings)
    command = "simharness " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["stress"] else ""
    paths = write_suite(out, result, command)
    print(paths["markdown"].read_text())
    print(f"wrote {paths['markdown']}, {paths['json']}, {paths['figure']}")
    return 0
