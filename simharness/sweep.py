"""`simharness sweep`: the closed loop over a grid of scenario settings -> one table and one figure.

Each `--set KEY=V1,V2,...` is one axis over a dotted scenario key (`demand_scale`, `road.width`,
`demand.motorcycle`, `ego.reaction`); several `--set` multiply into a grid. Every (grid point,
predictor, seed) is one closed-loop episode, and all of them go through one executor run (Ray starts
once). Per grid point and predictor: collision rate (share of episodes in which the ego collided),
near-miss rate, online prediction error (ADE/FDE, mean Euclidean, metres) and progress, each as a
mean with a 95% percentile-bootstrap confidence interval over seeds.

Outputs in `--out`: `sweep.json` (settings, seeds, versions, config hashes, every episode's scores),
`sweep.md` (the table) and `sweep.png` (collision rate and online ADE against the first swept key).
A failed episode is reported by grid point and seed; the others are scored (n is in the table).
"""

from __future__ import annotations

import dataclasses
import datetime
import itertools
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from simharness.closedloop import REFERENCE_EGOS, EpisodeJob, LoopConfig, bootstrap_ci, prepare_spec, run_episode
from simharness.closedloop.episode import raise_user_error
from simharness.errors import SimulatorError, UserError
from simharness.scenario import ScenarioSpec, load_scenario

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

# (figure name, per-episode score it averages, label)
METRICS = (("collision_rate", "collided", "collision rate"), ("near_miss_rate", "near_miss", "near-miss rate"),
           ("online_ade", "online_ade", "online ADE (m)"), ("online_fde", "online_fde", "online FDE (m)"),
           ("progress_m", "progress_m", "progress (m)"))


@dataclasses.dataclass(frozen=True)
class SweepJob:
    """One episode of one grid point (picklable for any executor)."""

    point: int  # index into the grid
    episode: EpisodeJob


def run_sweep_job(job: SweepJob) -> dict[str, Any]:
    """The job function: one episode -> its scores only (no Scene: a sweep keeps figures, not recordings)."""
    return run_episode(job.episode)["scores"]


def parse_value(text: str) -> Any:
    """A --set value as TOML would read it (1 -> int, 0.5 -> float, true -> bool), else the bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def build_grid(spec: ScenarioSpec, sets: Sequence[tuple[str, Sequence[str]]]) -> list[dict[str, Any]]:
    """Every combination of the axes (first axis slowest), each validated against the scenario schema.

    sets: [(dotted key, [value text, ...]), ...] -> [{key: value, ...}, ...]
    """
    if not sets:
        raise UserError("sweep: expected at least one --set KEY=V1,V2,... (e.g. --set demand_scale=0.5,1,2)")
    keys = [k for k, _ in sets]
    for key, values in sets:
        if not key:
            raise UserError("--set: empty key; expected KEY=V1,V2,...")
        if not values:
            raise UserError(f"--set {key}: no values; expected {key}=V1,V2,...")
        if keys.count(key) > 1:
            raise UserError(f"--set {key}: given twice; list all its values in one --set {key}=V1,V2,...")
    axes = [[parse_value(v) for v in values] for _, values in sets]
    grid = [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*axes)]
    top = {f.name for f in dataclasses.fields(ScenarioSpec)}
    for settings in grid:
        try:
            spec.with_overrides(settings)  # raises UserError naming the file and key on a bad key or value
        except UserError as e:
            near = [k.replace(".", "_") for k in settings if "." in k and k.replace(".", "_") in top]
            raise UserError(f"{e} (did you mean --set {near[0]}=...?)" if near else str(e)) from None
    return grid


def sweep(spec: ScenarioSpec, sets: Sequence[tuple[str, Sequence[str]]], predictors: Sequence[str],
          seeds: Sequence[int], out: Path, workers: int = 2, executor: str = "local", address: str | None = None,
          config: LoopConfig | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the grid and write sweep.json, sweep.md and sweep.png under `out`; returns what sweep.json holds.

    Returns {"info": {...}, "points": [{settings, predictor, config_hash, episodes, failed: {seed: error},
    <metric>: {mean, lo, hi, n} for each of METRICS}], "episodes": [per-episode scores + point index]}.
    """
    from tqdm import tqdm

    from simharness.executors import make_executor
    from simharness.io.parquet import software_versions

    config = config or LoopConfig()
    if not predictors:
        raise UserError("--predictor: expected a name (traphic, const-vel, oracle, none) or a run folder")
    grid = build_grid(spec, sets)
    if seeds:  # the seed the simulator gets stays 32-bit, or one line before any work
        spec.sim_seed(max(seeds))
    from simharness.plugins import check_predictor

    for name in predictors:
        check_predictor(name, REFERENCE_EGOS)  # a bad name fails now, before any process starts
    pool = make_executor(executor, workers, address)
    points = [{"settings": settings, "predictor": name, "spec": prepare_spec(spec.with_overrides(settings))}
              for settings in grid for name in predictors]
    jobs = [SweepJob(i, EpisodeJob(p["spec"], int(s), p["predictor"], config, keep_scene=False))
            for i, p in enumerate(points) for s in seeds]
    started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    scores: dict[int, list[dict[str, Any]]] = {i: [] for i in range(len(points))}
    failed: dict[int, dict[int, str]] = {i: {} for i in range(len(points))}
    bar = tqdm(total=len(jobs), desc=f"sweep {spec.name}", unit="ep", file=sys.stderr, disable=not progress,
               dynamic_ncols=True)
    try:
        for r in pool.map_unordered(run_sweep_job, jobs):
            if r.ok:
                scores[r.job.point].append(r.value)
            else:
                raise_user_error(r.error)  # bad input (an invalid forecast) is one line, not a failed episode
                error = r.error + (f" (after {r.attempts} attempts)" if r.attempts > 1 else "")
                failed[r.job.point][r.job.episode.seed] = error
                tqdm.write(f"{_label(points[r.job.point])} seed {r.job.episode.seed} failed: {error}", file=sys.stderr)
            bar.update(1)
            bar.set_postfix_str(f"{sum(map(len, failed.values()))} failed")
    finally:
        bar.close()
    rows = []
    for i, p in enumerate(points):
        eps = sorted(scores[i], key=lambda e: e["seed"])
        with_ego = [e for e in eps if e.get("ego_present")]
        row = {"settings": p["settings"], "predictor": p["predictor"], "config_hash": p["spec"].config_hash(),
               "episodes": len(eps), "episodes_with_ego": len(with_ego),
               "failed": {int(k): v for k, v in sorted(failed[i].items())}}
        row.update({name: bootstrap_ci([e.get(key) for e in with_ego]) for name, key, _ in METRICS})
        rows.append(row)
    info = {"scenario": spec.name, "config_hash": spec.config_hash(), "axes": {k: [parse_value(v) for v in vs]
            for k, vs in sets}, "predictors": list(predictors), "seeds": [int(s) for s in seeds],
            "loop": dataclasses.asdict(config), "executor": executor, "workers": workers, "started_utc": started,
            "seconds": round(time.perf_counter() - t0, 3), "command": sys.argv, "versions": software_versions(),
            "bootstrap": {"resamples": 2000, "level": 0.95, "seed": 0}}
    result = {"info": info, "points": rows,
              "episodes": [{"point": i, **e} for i in range(len(points)) for e in sorted(scores[i],
                                                                                      key=lambda e: e["seed"])]}
    write_outputs(Path(out), result)
    return result


def _label(point: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in point["settings"].items()) + f", {point['predictor']}"


def _ci(ci: dict[str, Any], digits: int = 2) -> str:
    if not ci or ci.get("n", 0) == 0:
        return "n/a"
    return f"{ci['mean']:.{digits}f} [{ci['lo']:.{digits}f}, {ci['hi']:.{digits}f}]"


def markdown_table(result: dict[str, Any]) -> str:
    """One row per grid point and predictor: mean [95% bootstrap CI] of each of METRICS."""
    keys = list(result["info"]["axes"])
    head = [*keys, "predictor", "episodes", *(label for _, _, label in METRICS), "failed seeds"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in result["points"]:
        cells = [str(row["settings"][k]) for k in keys] + [row["predictor"], str(row["episodes_with_ego"])]
        cells += [_ci(row[name]) for name, _, _ in METRICS]
        cells.append(", ".join(map(str, row["failed"])) or "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_outputs(out: Path, result: dict[str, Any]) -> None:
    """sweep.json, sweep.md, sweep.png, each written whole (temporary name, then rename)."""
    from simharness.io.parquet import atomic_write_bytes, dumps
    from simharness.report import plot_sweep

    out.mkdir(parents=True, exist_ok=True)
    info = result["info"]
    axis = next(iter(info["axes"]))
    groups = [", ".join([p["predictor"], *(f"{k}={v}" for k, v in p["settings"].items() if k != axis)])
              for p in result["points"]]
    plot_sweep([{**p, "group": g} for p, g in zip(result["points"], groups, strict=True)], axis, out / "sweep.png",
               title=f"{info['scenario']}: {len(info['seeds'])} seeds per point, mean and 95% bootstrap CI")
    text = (f"# Sweep of {info['scenario']} (config {info['config_hash']})\n\n"
            f"Seeds {info['seeds']}; mean [95% percentile-bootstrap CI] over episodes with an ego. "
            "Collision rate: share of episodes in which the ego collided; ADE/FDE: mean Euclidean (m).\n\n"
            + markdown_table(result) + "\n\n![sweep](sweep.png)\n")
    atomic_write_bytes(out / "sweep.md", text.encode())
    atomic_write_bytes(out / "sweep.json", (dumps(result, indent=1) + "\n").encode())


def sweep_command(args: Any) -> int:
    """`simharness sweep SCENARIO --set KEY=V1,V2 [--set ...] --seeds 0-9 [--predictor P[,P]] [--executor ray]`."""
    from simharness.io.folders import prepare_output

    spec = load_scenario(args.scenario)
    names = [n.strip() for n in str(args.predictor).split(",") if n.strip()]
    prepare_output(Path(args.out), getattr(args, "force", False))
    result = sweep(spec, args.sets, names, args.seeds, Path(args.out), args.workers, args.executor, args.address)
    print(markdown_table(result))
    out = Path(args.out)
    print(f"wrote {out / 'sweep.md'}, {out / 'sweep.json'}, {out / 'sweep.png'} "
          f"({result['info']['seconds']:.1f} s)")
    failures = [f"{_label(p)} seed {s}" for p in result["points"] for s in p["failed"]]
    if failures:
        raise SimulatorError(f"{len(failures)} episode(s) failed ({'; '.join(failures[:3])}); the table scores "
                             "the others")
    return 0
