"""`make demo`: the main job end to end, as a plain sequence of steps.

1. generate a small dense test set from the shipped arterial scenario (seeds the shipped weights never saw);
2. print its figures in the form of the TraPHic paper's Table 1, and draw one frame;
3. score the shipped TraPHic against constant velocity open-loop on it (ADE/FDE both ways, figures);
4. drive an ego in closed loop on TraPHic, constant-velocity, oracle and no forecasts; print the
   scorecard and write runs/demo/report.md with the tables, figures and one animation.

    python -m simharness.demo --out runs/demo
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from simharness.cli import run_guarded
from simharness.errors import SimulatorError
from simharness.evaluation import evaluate
from simharness.evaluation import format_table as format_eval_table
from simharness.generation import generate
from simharness.io.parquet import atomic_write_text
from simharness.predictors import load_predictor
from simharness.scenario import load_scenario
from simharness.stats import dataset_stats, format_table, write_frame_figure

SCENARIO = "sumo_arterial_dense"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m simharness.demo", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/demo"))
    p.add_argument("--seeds", type=int, default=2, help="scenes to generate (seeds 0..N-1)")
    p.add_argument("--duration", type=float, default=30.0, help="recorded seconds per scene")
    p.add_argument("--workers", type=int, default=2)
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
    print(format_table(stats))
    atomic_write_text(out / "stats.json", json.dumps(stats, indent=1, sort_keys=True) + "\n")

    # 3. one frame top-down
    figure = write_frame_figure(data, out / "frame.png")
    print(f"[3/5] figure: {figure}")

    # 4. open loop: the shipped TraPHic against constant velocity on the fresh scenes
    print("[4/5] open loop: shipped TraPHic vs constant velocity (all scenes of the fresh data set)")
    openloop = {}
    for name in ("traphic", "const-vel"):
        openloop[name] = evaluate(data, load_predictor(name), "traphic", split="all",
                                  figure_dir=out / "openloop" / name, progress=False, name=name)
        atomic_write_text(out / "openloop" / name / "metrics.json", json.dumps(openloop[name], indent=1) + "\n")
    table = format_eval_table(openloop)
    print(table)

    # 5. closed loop: an ego driven on TraPHic, constant-velocity and oracle forecasts, and with none
    from simharness.closedloop import demo_closed_loop

    print("[5/5] closed loop: egos on TraPHic, constant velocity, oracle and no prediction")
    report = demo_closed_loop(out, workers=args.workers, extra_md=(
        f"![one frame of the data set]({figure.name})\n\n## Open loop (shipped TraPHic vs constant velocity)"
        f"\n\n```\n{table}\n```\n\n![RMSE per horizon second](openloop/traphic/rmse_curve.png)\n"
        "![forecasts](openloop/traphic/forecasts.png)\n"))
    print(f"      report: {report}")
    print("\nwhere things are:")
    print(f"  data set     {data}  (_manifest.json + one Parquet shard per scene; _runs.jsonl logs each run)")
    print(f"  stats        {out / 'stats.json'}  (also: simharness stats {data})")
    print(f"  figure       {figure}")
    print(f"  open loop    {out / 'openloop'}  (metrics.json, rmse_curve.png, forecasts.png per predictor)")
    print(f"  closed loop  {out / 'closedloop'}  (scores.json, episodes, animation)")
    print(f"  report       {out / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
