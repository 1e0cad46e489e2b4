"""`make demo`: the main job end to end, as a plain sequence of steps.

1. generate a small dense test set from the shipped arterial scenario (seeds the shipped weights never saw);
2. print its figures in the form of the TraPHic paper's Table 1, and draw one frame;
3. score the shipped TraPHic against constant velocity open-loop on it (ADE/FDE both ways, RMSE per second);
4. drive an ego through the `stress/step_out` scenario on TraPHic's, constant velocity's, the oracle's and
   static forecasts, the same seeds for each; print the scorecard and write runs/demo/report.md with the
   tables, figures and two animations of one seed (an ego that collided, and the oracle ego on the same seed).

    python -m simharness.demo --out runs/demo
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from simharness.cli import run_guarded
from simharness.errors import SimulatorError, UserError
from simharness.evaluation import evaluate
from simharness.evaluation import format_table as format_eval_table
from simharness.generation import generate
from simharness.io.parquet import atomic_write_text
from simharness.predictors import load_predictor
from simharness.scenario import load_scenario
from simharness.stats import dataset_stats, format_table, write_frame_figure

SCENARIO = "sumo_arterial_dense"
# The closed loop's scenario: a scripted pedestrian that separates the egos (the oracle never at fault, static often).
STRESS = "stress/step_out"
EGOS = ("traphic", "const-vel", "oracle", "static")

LOOP_MD = (
    "`{scenario}`: {description}. One ego car is driven by the default planner on each forecaster's "
    "forecasts, through the same traffic on each seed: `traphic` (the shipped weights), `const-vel` (constant "
    "velocity), `oracle` (the true futures, from branches of the running simulation: the best a forecast can "
    "do) and `static` (everyone assumed to stand still: the floor).")


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m simharness.demo", description=__doc__.splitlines()[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder")
    p.add_argument("--seeds", type=int, default=2, help="data set scenes to generate (seeds 0..N-1)")
    p.add_argument("--duration", type=float, default=30.0, help="recorded seconds per data set scene")
    p.add_argument("--loop-seeds", type=int, default=6, help=f"closed-loop episodes of {STRESS} (seeds 0..N-1)")
    p.add_argument("--workers", type=int, default=2, help="parallel processes")
    args = p.parse_args(argv)
    return run_guarded(lambda: run_demo(args), prog="demo")


def run_demo(args: argparse.Namespace) -> int:
    """The steps, in order; errors propagate to `run_guarded`."""
    out: Path = args.out
    # 1. data: a small dense, heterogeneous, lane-less data set from SUMO
    spec = load_scenario(SCENARIO).with_overrides({"duration": args.duration})
    data = out / "data" / SCENARIO
    print(f"[1/5] generating {args.seeds} scenes of {SCENARIO} ({args.duration:g} s each) into {data}")
    run = generate(spec, list(range(args.seeds)), data, workers=args.workers)
    if run["failed"]:
        raise SimulatorError(f"seeds {sorted(run['failed'])} failed: {next(iter(run['failed'].values()))}")
    print(f"      {run['agent_frames']:,} agent-frames in {run['seconds']:.1f} s "
          f"({run['agent_frames_per_s']:,.0f}/s), {run['skipped']} scenes already there")

    # 2. its figures, in the form of the TraPHic paper's Table 1
    print("[2/5] data set figures")
    stats = dataset_stats(data)
    stats_text = format_table(stats)
    print(stats_text)
    atomic_write_text(out / "stats.json", json.dumps(stats, indent=1, sort_keys=True) + "\n")

    # 3. one frame top-down
    figure = write_frame_figure(data, out / "frame.png")
    print(f"[3/5] figure: {figure}")

    # 4. open loop: the shipped TraPHic against constant velocity on the fresh scenes
    print("[4/5] open loop: shipped TraPHic vs constant velocity (all scenes of the fresh data set)")
    openloop_md = open_loop(data, out / "openloop")

    # 5. closed loop: egos on each forecaster through a stress scenario, the same seeds for each
    from simharness.closedloop.page import write_report

    seeds = list(range(args.loop_seeds))
    print(f"[5/5] closed loop: {STRESS}, egos on {', '.join(EGOS)} forecasts, seeds {seeds}")
    loop_spec, _, shown = closed_loop(out / "closedloop", seeds, args.workers)
    data_md = (f"## Data set\n\nOne frame of `{SCENARIO}` ({args.seeds} scenes of {args.duration:g} s, seeds "
               f"0-{args.seeds - 1}; agents coloured by type, each with its last 3 s as a trail):\n\n"
               f"![one frame of the data set]({figure.name})\n\nIts figures, in the form of the TraPHic paper's "
               f"Table 1:\n\n```\n{stats_text}\n```\n\n    simharness generate {SCENARIO} --seeds 0-{args.seeds - 1} "
               f"--duration {args.duration:g} --out {data}\n    simharness stats {data}\n")
    intro = ("A dense, mixed, lane-less data set generated on SUMO; the shipped TraPHic against constant velocity "
             "on it (open loop); then an ego car driven on each forecaster's forecasts through a stress scenario "
             "(closed loop). Each section ends with the commands that reproduce it.\n")
    loop_md = (LOOP_MD.format(scenario=STRESS, description=loop_spec.description) + " " + shown
               + f"\n\n    simharness closedloop {STRESS} --predictor {','.join(EGOS)} --seeds 0-{seeds[-1]}")
    report = write_report(out, title="simharness demo", extra_md="\n".join([intro, data_md, openloop_md]),
                          closedloop_dir=out / "closedloop", loop_md=loop_md)
    print(f"      report: {report}")
    print("\nwhere things are:")
    print(f"  data set     {data}  (_manifest.json + one Parquet shard per scene; _runs.jsonl logs each run)")
    print(f"  stats        {out / 'stats.json'}  (also: simharness stats {data})")
    print(f"  figure       {figure}")
    print(f"  open loop    {out / 'openloop'}  (metrics.json per predictor, rmse_curve.png, traphic/forecasts.png)")
    print(f"  closed loop  {out / 'closedloop'}  (scores.json and episodes per ego, scorecard.png, animations)")
    print(f"  report       {out / 'report.md'}")
    return 0


def open_loop(data: Path, out: Path) -> str:
    """Shipped TraPHic and constant velocity on every scene of `data`: metrics.json each, TraPHic's forecast
    figure, one RMSE-per-second figure with both; returns the report's markdown section."""
    from simharness.report import plot_rmse_curve

    metrics = {}
    for name in ("traphic", "const-vel"):
        metrics[name] = evaluate(data, load_predictor(name), "traphic", split="all", progress=False, name=name,
                                 figure_dir=out / name if name == "traphic" else None)
        (out / name).mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / name / "metrics.json", json.dumps(metrics[name], indent=1) + "\n")
    table = format_eval_table(metrics)
    print(table)
    units = metrics["traphic"].get("units", "m")
    curve = plot_rmse_curve({n: m["rmse_per_second"] for n, m in metrics.items()}, out / "rmse_curve.png",
                            units=units, title="RMSE per horizon second: shipped TraPHic and constant velocity")
    rel = Path(out.name)
    return (f"## Open loop: shipped TraPHic and constant velocity\n\nEach agent's next 5 s forecast from its "
            f"last 3 s (5 Hz), on every scene of the data set above (seeds the shipped weights never saw); ADE/FDE "
            f"as mean Euclidean error and as the TraPHic paper's RMSE, in {units}:\n\n```\n{table}\n```\n\n"
            f"![RMSE per horizon second]({(rel / curve.name).as_posix()})\n\nTraPHic's forecasts for four agents "
            f"(history black, truth green, forecast red with 1-sigma ellipses):\n\n"
            f"![forecasts]({(rel / 'traphic' / 'forecasts.png').as_posix()})\n\n"
            f"    simharness evaluate --data {data} --model traphic --split all\n"
            f"    simharness evaluate --data {data} --model const-vel --split all\n")


def closed_loop(out: Path, seeds: list[int], workers: int) -> tuple[Any, dict[str, dict[str, Any]], str]:
    """Every ego of EGOS over `seeds` on STRESS: scores and episodes under out/<ego>/, and two animations of
    one seed: the oracle ego and the first ego (in EGOS order) that collided at fault on a seed where the
    oracle did not (else the oracle and constant velocity on the first seed). Returns the spec, the scores and
    a sentence saying what the animations show."""
    from simharness.closedloop import prepare_spec, run_closed_loop, scorecard_table, write_run

    spec = prepare_spec(load_scenario(STRESS))
    egos = list(EGOS)
    try:
        load_predictor("traphic")
    except (UserError, OSError) as e:
        print(f"      (TraPHic left out of the closed loop: {e})", file=sys.stderr)
        egos.remove("traphic")
    # forecasts are kept for every seed (small: a few hundred per episode), so any one can be animated
    results = {ego: run_closed_loop(spec, ego, seeds, workers=workers, keep_forecasts=seeds) for ego in egos}

    def hit(ego: str, i: int) -> bool:
        return bool(results[ego][i]["scores"]["at_fault_collided"])

    shown = next(((ego, i) for i in range(len(seeds)) if not hit("oracle", i)
                  for ego in egos if ego != "oracle" and hit(ego, i)), ("const-vel", 0))
    scores = {}
    for ego in egos:
        for i, r in enumerate(results[ego]):
            if i != shown[1]:
                r.pop("forecasts", None)  # only the chosen seed is animated
        scores[ego] = write_run(out / ego, spec, ego, results[ego], animate=int(ego in ("oracle", shown[0])))
    print(f"{spec.name}, seeds {seeds} x {spec.duration:g} s (mean [95% bootstrap CI])")
    print(scorecard_table(scores))
    collided = hit(shown[0], shown[1])
    note = (f"The animations at the end show seed {seeds[shown[1]]}: the `{shown[0]}` ego "
            + ("collides at fault, the `oracle` ego in the same traffic does not." if collided else
               "and the `oracle` ego in the same traffic."))
    return spec, scores, note


if __name__ == "__main__":
    sys.exit(main())
