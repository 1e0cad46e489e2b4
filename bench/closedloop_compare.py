"""Closed-loop speed and results, this tree against another checkout of the project (e.g. main), back to back.

Each episode runs in a fresh process (`python -c`, PYTHONPATH = the tree), the two trees alternating per
episode and repeat (the machine's load shifts: compare within one run). Results must not change with a speed-up:
every score that is not a timing (online errors, collisions, progress, oracle counters, ...) is compared
exactly and any difference is printed. Speed: simulated seconds per wall second, loop only (warm-up excluded), and
the wall (with --cpu: CPU) ms per simulated second of simulator / predictor (the oracle's branches included) /
planner.

    .venv/bin/python bench/closedloop_compare.py --baseline /work/main
    .venv/bin/python bench/closedloop_compare.py --baseline /work/main --egos oracle --seeds 0-2 --duration 20

Exit status 1 when any result differs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# One episode in the given tree: its scores as JSON on the last line of stdout.
_EPISODE = """
import json, sys
from simharness.closedloop import EpisodeJob, LoopConfig, prepare_spec, run_episode
from simharness.scenario import load_scenario
scenario, reaction, ego, seed, duration, cpu = sys.argv[1:7]
if cpu == "1":  # the loop's timers read this process's CPU time instead of the wall clock
    import time, types
    import simharness.closedloop.episode as episode
    episode.time = types.SimpleNamespace(perf_counter=time.process_time)
spec = prepare_spec(load_scenario(scenario), reaction).with_overrides({"duration": float(duration)})
s = run_episode(EpisodeJob(spec, int(seed), ego, LoopConfig(), keep_scene=False))["scores"]
print(json.dumps({k: v for k, v in s.items() if isinstance(v, (int, float, str, bool)) or v is None}))
"""
TIMING = ("wall_s", "realtime_factor", "realtime_factor_with_warmup", "cpu_all_s")
# With --cpu, every Python process of the episode (its SUMO worker and the worker's forks, which end in os._exit)
# appends its own CPU seconds to a log on the way out, so that the episode's CPU over all processes adds up.
_SITECUSTOMIZE = """
import atexit, os
_log, _exit, _pid = os.environ.get("CLOSEDLOOP_CPU_LOG"), os._exit, os.getpid()
def _note():
    if _log:
        t = os.times()
        with open(_log, "a") as f:
            f.write(f"{os.getpid()} {t.user + t.system}\\n")
def _exit_noting(code):
    _note()
    _exit(code)
os._exit = _exit_noting
atexit.register(_note)
"""


def run(tree: Path, scenario: str, reaction: str, ego: str, seed: int, duration: float, cpu: bool) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    tmp = tempfile.TemporaryDirectory()
    if cpu:
        (Path(tmp.name) / "sitecustomize.py").write_text(_SITECUSTOMIZE)
        env["PYTHONPATH"] = os.pathsep.join([tmp.name, str(tree)])
        env["CLOSEDLOOP_CPU_LOG"] = str(Path(tmp.name) / "cpu.log")
    out = subprocess.run([sys.executable, "-c", _EPISODE, scenario, reaction, ego, str(seed), str(duration),
                          str(int(cpu))],
                         cwd=tree, env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"{tree}: {scenario} {ego} seed {seed} failed:\n{out.stderr[-2000:]}")
    scores = json.loads(out.stdout.strip().splitlines()[-1])
    if cpu:  # CPU s of every process of the episode, reset and warm-up included
        log = Path(tmp.name) / "cpu.log"
        lines = log.read_text().splitlines() if log.exists() else []
        scores["cpu_all_s"] = sum(float(line.split()[1]) for line in lines)
    tmp.cleanup()
    return scores


def differences(a: dict, b: dict) -> list[str]:
    """Keys whose values differ (timings left out); nan equals nan."""
    out = []
    for k in sorted(set(a) | set(b)):
        if k in TIMING or k.startswith("time_"):
            continue
        va, vb = a.get(k), b.get(k)
        if va != vb and not (isinstance(va, float) and isinstance(vb, float) and va != va and vb != vb):
            out.append(f"{k}: {va!r} -> {vb!r}")
    return out


def per_sim_s(s: dict) -> str:
    return " / ".join(f"{s[f'time_{k}_s'] / s['sim_s'] * 1000:.0f}" for k in ("sim", "predict", "plan"))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--baseline", type=Path, required=True, help="the other checkout (its root folder)")
    p.add_argument("--scenarios", default="sumo_arterial_dense")
    p.add_argument("--egos", default="traphic,oracle")
    p.add_argument("--reaction", default="cut_in")
    p.add_argument("--seeds", default="0", help="comma-separated or a range a-b")
    p.add_argument("--duration", type=float, default=60.0, help="recorded seconds per episode")
    p.add_argument("--repeats", type=int, default=1, help="runs of each episode per tree (speed only)")
    p.add_argument("--cpu", action="store_true", help="time the loop in CPU s of the episode's process, not wall s "
                   "(load-independent; the SUMO oracle's branches run in worker processes: for it, read the added "
                   "column, simulated s per CPU s summed over all the episode's processes, warm-up included)")
    args = p.parse_args()
    lo, _, hi = args.seeds.partition("-")
    seeds = list(range(int(lo), int(hi) + 1)) if hi else [int(s) for s in args.seeds.split(",")]
    trees = {"baseline": args.baseline.resolve(), "this": ROOT}
    print(f"== closed loop, {args.duration:g} s episodes, reaction {args.reaction}, seeds {args.seeds}, "
          f"{'CPU' if args.cpu else 'wall'} time; "
          f"baseline {trees['baseline']}, this {trees['this']}")
    cpu_col = "simulated s per CPU s of all processes (incl. warm-up), baseline -> this | " if args.cpu else ""
    print("| scenario | ego | seed | x real time, baseline -> this | ratio | " + cpu_col
          + "ms per simulated s: sim / predict / plan, baseline -> this | results |")
    print("|---|---|---|---|---|---|---|" + ("---|" if args.cpu else ""))
    bad = 0
    for scenario in args.scenarios.split(","):
        for ego in args.egos.split(","):
            for seed in seeds:
                runs: dict[str, list[dict]] = {"baseline": [], "this": []}
                for r in range(args.repeats):
                    for name in (("baseline", "this") if r % 2 == 0 else ("this", "baseline")):  # alternate
                        runs[name].append(run(trees[name], scenario, args.reaction, ego, seed, args.duration,
                                             args.cpu))
                diff = [d for s in runs["this"] for d in differences(runs["baseline"][0], s)]
                diff += [d for s in runs["baseline"][1:] for d in differences(runs["baseline"][0], s)]
                bad += bool(diff)
                rt = {n: [s["realtime_factor"] for s in v] for n, v in runs.items()}
                best = {n: max(v, key=lambda s: s["realtime_factor"]) for n, v in runs.items()}
                fmt = {n: ", ".join(f"{x:.2f}x" for x in v) for n, v in rt.items()}
                ratio = (sum(rt["this"]) / len(rt["this"])) / (sum(rt["baseline"]) / len(rt["baseline"]))
                cpu = ""
                if args.cpu:  # all processes: simulated s per CPU s, the reset and warm-up included
                    per = {n: ", ".join(f"{s['sim_s'] / s['cpu_all_s']:.2f}x" for s in v) for n, v in runs.items()}
                    cpu = f"{per['baseline']} -> {per['this']} | "
                print(f"| {scenario} | {ego} | {seed} | {fmt['baseline']} -> {fmt['this']} | {ratio:.2f} | {cpu}"
                      f"{per_sim_s(best['baseline'])} -> {per_sim_s(best['this'])} | "
                      + ("identical" if not diff else "DIFFER: " + "; ".join(diff[:6])) + " |", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
