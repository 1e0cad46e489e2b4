"""Executors on one machine: local process pool vs Ray, both with the same number of workers, in one run.

1. Ray's start-up (a local instance, `ray.init`) on its own, and the fixed cost of one job on each
   executor (a no-op job: a fresh process each, spawned locally, a `max_calls=1` Ray worker).
2. `generate` of the same seeds of the dense arterial on the local pool and on Ray (the instance
   already up, so start-up is not counted twice): wall time, agent-frames per second, ratio, and
   whether the two data sets are byte-identical.
3. On paper: one million scenes, from the figures measured here (core-seconds per scene, bytes per
   scene from the shards written, cores needed to generate them in a day).

With --episodes N, only this instead: N short closed-loop episodes (what sensitivity, sweep, benchmark
and closedloop run) on the local pool with a fresh process per job (`jobs_per_worker=1`, the former
executor) and with reused workers, alternately, `--rounds` times each in one run: wall time per
episode, the ratio, and whether both gave the same scores.

    python bench/executors.py [--seeds 8] [--workers 2] [--duration 60]
    python bench/executors.py --episodes 20 [--workers 2] [--rounds 2]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

# bench/predictor.py is named like the `predictor` package: drop bench/ from the path (workers inherit it).
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
os.environ.setdefault("OMP_NUM_THREADS", "1")

from simharness.executors import LocalExecutor, RayExecutor, import_ray, start_local_ray  # noqa: E402
from simharness.generation import MANIFEST_EVERY_S, generate  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402

SCENARIO = "sumo_arterial_dense"
SCENES = 1_000_000
DAY_S = 86_400


def noop(i: int) -> int:
    return i


def job_overhead(pool, n: int) -> float:  # noqa: ANN001 - any Executor
    """Seconds per no-op job at the pool's parallelism (process start, imports, result back)."""
    t0 = time.perf_counter()
    results = list(pool.map_unordered(noop, range(n)))
    if not all(r.ok for r in results):
        sys.exit(f"no-op job failed: {[r.error for r in results if not r.ok]}")
    return (time.perf_counter() - t0) / n


def episode_scores(job):  # noqa: ANN001, ANN201 - an EpisodeJob -> its scores without timings
    from simharness.closedloop import run_episode

    s = run_episode(job)["scores"]
    return {k: v for k, v in s.items() if k not in ("wall_s", "realtime_factor", "realtime_factor_with_warmup")
            and not k.startswith("time_")}


def episodes(n: int, workers: int, rounds: int) -> None:
    """Fresh process per episode vs reused workers on the same short highway episodes, alternately."""
    from simharness.closedloop import EpisodeJob, prepare_spec

    spec = prepare_spec(load_scenario("highway_mixed_dense"), "cut_in").with_overrides(
        {"duration": 6.0, "warmup": 5.0, "ego.insert_at": 2.0})
    jobs = [EpisodeJob(spec, s, "const-vel", keep_scene=False) for s in range(n)]
    print(f"{n} closed-loop episodes of highway_mixed_dense (cut_in, {spec.warmup:g} s warm-up + {spec.duration:g} s,"
          f" const-vel), {workers} workers, {rounds} round(s) each, alternating; {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at the start")
    times: dict[str, list[float]] = {"fresh": [], "reused": []}
    scores = {}
    for _ in range(rounds):
        for name, per in (("fresh", 1), ("reused", None)):
            t0 = time.perf_counter()
            res = list(LocalExecutor(workers, jobs_per_worker=per).map_unordered(episode_scores, jobs))
            times[name].append(time.perf_counter() - t0)
            if not all(r.ok for r in res):
                sys.exit(f"{name}: {[r.error for r in res if not r.ok][:3]}")
            scores[name] = {r.job.seed: r.value for r in res}
    for name, ts in times.items():
        print(f"  {name:6s} workers: {min(ts):7.2f} s best of {rounds} ({min(ts) / n:.2f} s per episode; all: "
              + ", ".join(f"{x:.2f}" for x in ts) + ")")
    print(f"  fresh / reused: {min(times['fresh']) / min(times['reused']):.2f}x; same scores: "
          f"{scores['fresh'] == scores['reused']}; load average {os.getloadavg()[0]:.1f} at the end")


def same_bytes(a: Path, b: Path) -> bool:
    names = sorted(p.name for p in a.iterdir() if p.name != "runs.jsonl")
    return names == sorted(p.name for p in b.iterdir() if p.name != "runs.jsonl") and all(
        (a / n).read_bytes() == (b / n).read_bytes() for n in names)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=8, help="scenes per executor")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--duration", type=float, default=None, help="recorded seconds per scene (default: scenario's)")
    p.add_argument("--episodes", type=int, default=None, help="only: fresh vs reused workers on N short episodes")
    p.add_argument("--rounds", type=int, default=2, help="with --episodes: runs of each, alternating")
    args = p.parse_args()
    if args.episodes:
        episodes(args.episodes, args.workers, args.rounds)
        return
    ray = import_ray()
    spec = load_scenario(SCENARIO)
    if args.duration is not None:
        spec = spec.with_overrides({"duration": args.duration})
    seeds = list(range(args.seeds))
    w = args.workers
    print(f"scenario {SCENARIO}: {spec.warmup:g} s warm-up + {spec.duration:g} s recorded at {spec.record_hz:g} Hz; "
          f"{len(seeds)} scenes per executor, {w} workers; {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at the start (other work on these cores skews every figure)")
    startup = start_local_ray(w)
    try:
        print(f"  Ray start-up (local instance, ray.init)   {startup:7.2f} s")
        local_job = job_overhead(LocalExecutor(w), 4 * w)
        ray_job = job_overhead(RayExecutor(w), 4 * w)
        print(f"  fixed cost per job (no-op, {w} at a time)   local {local_job:.2f} s, Ray {ray_job:.2f} s")
        with tempfile.TemporaryDirectory() as tmp:
            runs = {}
            for name in ("local", "ray"):
                s = generate(spec, seeds, Path(tmp) / name, workers=w, executor=name, progress=True)
                if s["failed"]:
                    sys.exit(f"{name}: generation failed: {s['failed']}")
                runs[name] = s
                print(f"  generate on {name:5s}: {s['seconds']:7.2f} s  {s['agent_frames_per_s']:10,.0f} agent-frames/s"
                      f"  ({s['agent_frames']:,} agent-frames; {s['job_seconds'] / len(seeds):.2f} s per scene in "
                      "its worker)")
            loc, ry = runs["local"], runs["ray"]
            identical = same_bytes(Path(tmp) / "local", Path(tmp) / "ray")
            ratio = ry["agent_frames_per_s"] / loc["agent_frames_per_s"]
            print(f"  Ray / local throughput                  {ratio:7.3f}   data sets byte-identical: {identical}")
            print(f"  Ray including its start-up              "
                  f"{ry['agent_frames'] / (ry['seconds'] + startup):10,.0f} agent-frames/s")
            shards = sorted((Path(tmp) / "local").glob("scene-*.parquet"))
            bytes_per_scene = sum(p.stat().st_size for p in shards) / len(shards)
            manifest_per_scene = (Path(tmp) / "local" / "_manifest.json").stat().st_size / len(shards)
    finally:
        ray.shutdown()
    # On paper: the better of the two runs, per core (each worker is one single-threaded simulation).
    best = min(loc["seconds"], ry["seconds"])
    core_s = best * w / len(seeds)  # core-seconds per scene, warm-up included
    frames_per_scene = loc["agent_frames"] / len(seeds)
    per_scene = bytes_per_scene + manifest_per_scene
    print(f"\none million scenes of {SCENARIO} ({spec.duration:g} s each), from these figures:")
    print(f"  throughput per core        {frames_per_scene / core_s:10,.0f} agent-frames/s, "
          f"{DAY_S / core_s:,.0f} scenes per core-day ({core_s:.2f} core-s per scene, "
          f"{spec.warmup / (spec.warmup + spec.duration):.0%} of simulated time is warm-up)")
    print(f"  storage per scene          {per_scene / 1e3:10,.1f} kB ({bytes_per_scene / 1e3:.1f} kB shard + "
          f"{manifest_per_scene:.0f} B manifest entry; {frames_per_scene:,.0f} agent-frames, "
          f"{bytes_per_scene / frames_per_scene:.1f} B each)")
    print(f"  1M scenes                  {SCENES * core_s / 3600:10,.0f} core-hours, "
          f"{SCENES * per_scene / 1e9:,.0f} GB, {SCENES * frames_per_scene / 1e9:,.1f} billion agent-frames")
    cores = math.ceil(SCENES * core_s / DAY_S)
    print(f"  cores for one day          {cores:10,d} (e.g. {math.ceil(cores / 64):,d} "
          f"node(s) of 64 cores), manifest {SCENES * manifest_per_scene / 1e6:,.0f} MB, refreshed every "
          f"{MANIFEST_EVERY_S:g} s of a run (split a run that large into data sets of ~10k scenes)")


if __name__ == "__main__":
    main()
