"""Closed-loop benchmark: speed with TraPHic in the loop, and the scorecard of the four egos.

1. Simulated seconds per wall second of one closed-loop episode with TraPHic driving the ego, and with
   the exact oracle, on the dense SUMO arterial and the dense highway (loop only, and including the
   unrecorded warm-up), with the time split between simulator, predictor and planner. Targets: TraPHic
   >= 15x real time on one core, the exact oracle >= 5x on SUMO.
2. The scorecard of the four egos (traphic, const-vel, oracle, none), plus "static" (the same planner
   with no prediction: everyone assumed to stay put), over seeds of the stress setting
   (background reaction "cut_in"), mean [95% bootstrap CI], written with figures to --out.

    .venv/bin/python bench/closedloop.py            # --quick: 6 seeds of 30 s, a few minutes on 2 cores
    .venv/bin/python bench/closedloop.py --full     # 20 seeds of 60 s
    .venv/bin/python bench/closedloop.py --speed-only --against DIR   # part 1 against another checkout

--against DIR: part 1's episodes also run by the checkout at DIR (e.g. `git archive REV | tar -x -C DIR`), each
episode in a worker process of its checkout, the two checkouts taking turns for --rounds rounds: both speeds and
their ratio, measured in one run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# bench/ holds a script named predictor.py: keep it from shadowing the `predictor` package.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

from simharness.closedloop import (  # noqa: E402
    EpisodeJob,
    LoopConfig,
    prepare_spec,
    run_closed_loop,
    run_episode,
    scorecard_table,
    write_run,
)
from simharness.closedloop.page import write_report  # noqa: E402
from simharness.errors import UserError  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402

EGOS = ("traphic", "const-vel", "oracle", "static", "none")


SPEED_KEYS = ("sim_s", "wall_s", "realtime_factor", "realtime_factor_with_warmup", "time_sim_s", "time_predict_s",
              "time_plan_s", "time_reset_s")


def speed_episode(scenario: str, reaction: str, duration: float, ego: str) -> dict[str, float]:
    """One closed-loop episode, seed 0, in this process: the scores part 1 prints."""
    spec = prepare_spec(load_scenario(scenario), reaction).with_overrides({"duration": duration})
    s = run_episode(EpisodeJob(spec, 0, ego, LoopConfig(), keep_scene=False))["scores"]
    return {k: float(s[k]) for k in SPEED_KEYS}


def against(other: Path, scenarios: list[str], reaction: str, duration: float, egos: list[str],
            rounds: int) -> list[tuple[str, str, list[float], list[float]]]:
    """Simulated s per wall s (loop only) of each (scenario, ego) episode run by this checkout and by the one at
    `other`, each episode in a fresh worker process of its own checkout, the two alternating: rows (scenario, ego,
    this checkout's figures, the other's)."""
    roots = {"this": Path(__file__).resolve().parents[1], "other": other.resolve()}
    rows = []
    for scenario in scenarios:
        for ego in egos:
            got: dict[str, list[float]] = {"this": [], "other": []}
            for _ in range(rounds):
                for name, root in roots.items():
                    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--serve-episode", scenario,
                                          reaction, str(duration), ego], cwd=root, capture_output=True, text=True,
                                         env={**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"})
                    last = out.stdout.strip().splitlines()[-1:] if out.returncode == 0 else []
                    if not last:
                        raise SystemExit(f"--against: the {name} checkout ({root}) failed on {scenario} with {ego}: "
                                         + (out.stderr.strip().splitlines() or ["no output"])[-1])
                    res = json.loads(last[0])
                    if res["root"] != str(root):  # the worker must run that checkout's simharness, not an installed one
                        raise SystemExit(f"--against: the worker for {root} imported simharness from {res['root']}")
                    got[name].append(res["realtime_factor"])
            rows.append((scenario, ego, got["this"], got["other"]))
    return rows


def main() -> int:
    if sys.argv[1:2] == ["--serve-episode"]:  # worker of `against`: one episode with this process's simharness
        import simharness

        scenario, reaction, duration, ego = sys.argv[2:6]
        root = str(Path(simharness.__file__).resolve().parents[1])
        print(json.dumps({"root": root, **speed_episode(scenario, reaction, float(duration), ego)}))
        return 0
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = p.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="6 seeds of 30 s (default)")
    g.add_argument("--full", action="store_true", help="20 seeds of 60 s")
    p.add_argument("--scenario", default="sumo_arterial_dense")
    p.add_argument("--reaction", default="cut_in")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/bench_closedloop"))
    p.add_argument("--traphic", default="traphic", help="TraPHic to use: 'traphic' (shipped) or a run folder")
    p.add_argument("--speed-scenarios", default="sumo_arterial_dense,highway_mixed_dense")
    p.add_argument("--speed-duration", type=float, default=60.0, help="recorded seconds of the speed episodes")
    p.add_argument("--speed-only", action="store_true", help="part 1 only")
    p.add_argument("--against", type=Path, default=None, help="part 1 also by the checkout at this directory")
    p.add_argument("--rounds", type=int, default=2, help="turns each checkout takes with --against")
    args = p.parse_args()
    seeds, duration = (list(range(20)), 60.0) if args.full else (list(range(6)), 30.0)
    spec = prepare_spec(load_scenario(args.scenario), args.reaction).with_overrides({"duration": duration})
    egos = [args.traphic if e == "traphic" else e for e in EGOS]
    try:
        from simharness.predictors import load_predictor

        load_predictor(args.traphic)
    except (UserError, ImportError, OSError) as e:
        print(f"note: TraPHic not available ({e}); scorecard without it", file=sys.stderr)
        egos.remove(args.traphic)
    traphic = args.traphic if args.traphic in egos else None

    # 1. Speed: one episode per ego and scenario in this process (one core; nothing else of ours running).
    speed_egos = [(traphic or "const-vel", 15.0), ("oracle", 5.0)]
    for scenario in args.speed_scenarios.split(","):
        sspec = prepare_spec(load_scenario(scenario), args.reaction).with_overrides({"duration": args.speed_duration})
        for name, target in speed_egos:
            s = speed_episode(scenario, args.reaction, args.speed_duration, name)
            print(f"== closed-loop speed: {name} in the loop, {scenario}, reaction {sspec.ego.reaction}, seed 0")
            print(f"recorded {s['sim_s']:.0f} s (+ {sspec.warmup:.0f} s warm-up), wall {s['wall_s']:.1f} s")
            print(f"simulated s per wall s, loop only:          {s['realtime_factor']:.1f}x   (target >= {target:g}x)")
            print(f"simulated s per wall s, incl. warm-up:      {s['realtime_factor_with_warmup']:.1f}x")
            per = {k: s[f"time_{k}_s"] / s["sim_s"] * 1000 for k in ("sim", "predict", "plan")}
            print("wall ms per simulated s: " + ", ".join(f"{k} {v:.0f}" for k, v in per.items())
                  + f"; reset+warm-up {s['time_reset_s']:.1f} s", flush=True)
    if args.against is not None:
        print(f"\n== against {args.against}: simulated s per wall s, loop only, each episode in a worker process of "
              f"its checkout, {args.rounds} turns each")
        for scenario, ego, mine, theirs in against(args.against, args.speed_scenarios.split(","), args.reaction,
                                                   args.speed_duration, [e for e, _ in speed_egos], args.rounds):
            a, b = sum(mine) / len(mine), sum(theirs) / len(theirs)
            print(f"{scenario:22s} {ego:10s} this {', '.join(f'{x:.1f}x' for x in mine)}; other "
                  f"{', '.join(f'{x:.1f}x' for x in theirs)}; mean ratio this / other {a / b:.2f}", flush=True)
    if args.speed_only:
        return 0

    # 2. Scorecard over seeds.
    print(f"\n== scorecard: {len(seeds)} seeds x {duration:.0f} s, {spec.name}, reaction {spec.ego.reaction}")
    scores = {}
    t1 = time.perf_counter()
    for ego in egos:
        results = run_closed_loop(spec, ego, seeds, workers=args.workers, keep_forecasts=seeds[:1])
        label = "traphic" if ego == traphic else ego
        scores[label] = write_run(args.out / label, spec, label, results, animate=1 if ego == egos[0] else 0)
    print(scorecard_table(scores))
    print(f"(scorecard wall time {time.perf_counter() - t1:.0f} s with {args.workers} workers)")
    report = write_report(args.out, title=f"Closed-loop benchmark: {spec.name}, reaction {spec.ego.reaction}")
    print(f"report: {report}")
    if "traphic" in scores:
        col = {k: scores[k]["collision_rate"]["mean"] for k in ("traphic", "none")}
        prog = {k: scores[k]["progress_m"]["mean"] for k in ("traphic", "const-vel")}
        print(f"check: TraPHic collision rate {col['traphic']:.2f} vs no prediction {col['none']:.2f} -> "
              + ("lower" if col["traphic"] < col["none"] else "NOT lower"))
        print(f"check: TraPHic progress {prog['traphic']:.1f} m vs const-vel {prog['const-vel']:.1f} m -> "
              + ("at least as much" if prog["traphic"] >= prog["const-vel"] else "LESS"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
