"""Generation throughput on the dense arterial, measured in one run.

1. Harness overhead: recorded agent-frames per second through the harness (stepping + reading every
   agent + building the Scene + writing the Parquet shard) against raw libsumo stepping of the same
   scenario and seed without recording (`SumoSimulator.advance_unrecorded`). Both start from the same
   warmed-up state (same seed, deterministic), so they cover the same agent-frames; ratio = raw time /
   harness time (target >= 0.85). Each side runs in its own process (libsumo: one simulation per
   process), alternated, best of `--repeat`. Raw stepping does the same simulation work as the
   harness, and only that: the SUMO steps, plus the harness-driven parts of the simulation (crossing
   pedestrians' gap decisions once per frame on one read of every vehicle's position and speed, which
   the recorded path takes from the frame it has just recorded; collision and teleport bookkeeping);
   it reads no other variable, builds no Frame. Both end in the same state (tests/test_sumo.py).
   Wall time and this process's CPU time are both reported: on a shared machine the CPU-time ratio
   is the one other work does not skew.
2. Scaling: `generate` of the same seeds with 1 worker and with 2 workers (target >= 1.7x).

    python bench/generate.py [--duration 60] [--seeds 4] [--repeat 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from simharness.executors import LocalExecutor  # noqa: E402
from simharness.generation import generate  # noqa: E402
from simharness.io.parquet import write_scene  # noqa: E402
from simharness.scenario import ScenarioSpec, load_scenario  # noqa: E402

SCENARIO = "sumo_arterial_dense"


def harness_run(job: tuple[ScenarioSpec, int, str]) -> dict[str, float]:
    """Warm up, then record every frame, build the Scene and write its shard; timings in seconds."""
    from simharness.sim import make_simulator, scene_from_frames

    spec, seed, out = job
    sim = make_simulator(spec)
    t0 = time.perf_counter()
    frames = [sim.reset(seed)]
    t1, c1 = time.perf_counter(), time.process_time()
    frames += [sim.step() for _ in range(spec.num_frames - 1)]
    t2 = time.perf_counter()
    scene = scene_from_frames(frames, spec.dt, {"seed": seed, "road": sim.road.to_dict()})
    t3 = time.perf_counter()
    rows = write_scene(scene, Path(out) / f"bench-{seed}.parquet", f"bench-{seed}")
    t4, c4 = time.perf_counter(), time.process_time()
    sim.close()
    return {"warmup": t1 - t0, "record": t2 - t1, "scene": t3 - t2, "write": t4 - t3, "rows": rows,
            "agent_frames_after_first": rows - frames[0].num_agents, "cpu": c4 - c1}


def raw_run(job: tuple[ScenarioSpec, int, str]) -> dict[str, float]:
    """Warm up, then step the same frames without reading any agent."""
    from simharness.sim import make_simulator

    spec, seed, _ = job
    sim = make_simulator(spec)
    t0 = time.perf_counter()
    sim.reset(seed)
    t1, c1 = time.perf_counter(), time.process_time()
    sim.advance_unrecorded(spec.num_frames - 1)
    t2, c2 = time.perf_counter(), time.process_time()
    sim.close()
    return {"warmup": t1 - t0, "step": t2 - t1, "cpu": c2 - c1}


def one(fn, job):  # noqa: ANN001, ANN201 - a single job in its own process
    (result,) = LocalExecutor(1).map_unordered(fn, [job])
    if not result.ok:
        sys.exit(f"bench job failed: {result.error}\n{result.traceback}")
    return result.value


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=60.0, help="recorded seconds per scene")
    p.add_argument("--seeds", type=int, default=4, help="scenes for the scaling part")
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args()
    spec = load_scenario(SCENARIO).with_overrides({"duration": args.duration})
    with tempfile.TemporaryDirectory() as tmp:
        # 1. overhead of recording + Parquet writing against raw stepping
        harness, raw = [], []
        for _ in range(args.repeat):
            harness.append(one(harness_run, (spec, 0, tmp)))
            raw.append(one(raw_run, (spec, 0, tmp)))
        h = min(harness, key=lambda r: r["record"] + r["scene"] + r["write"])
        r = min(raw, key=lambda r: r["step"])
        af = h["agent_frames_after_first"]
        h_time = h["record"] + h["scene"] + h["write"]
        print(f"scenario {SCENARIO}, {args.duration:g} s recorded at {spec.record_hz:g} Hz after {spec.warmup:g} s "
              f"warm-up; {h['rows']:,} agent-frames ({h['rows'] / spec.num_frames:.0f} agents per frame)")
        print(f"  raw stepping (no recording)         {r['step']:7.2f} s  {af / r['step']:10,.0f} agent-frames/s")
        print(f"  harness (record + Scene + Parquet)  {h_time:7.2f} s  {af / h_time:10,.0f} agent-frames/s  "
              f"[step+read {h['record']:.2f} s, Scene {h['scene']:.3f} s, Parquet {h['write']:.3f} s]")
        print(f"  ratio harness/raw                   {r['step'] / h_time:7.3f}   (target >= 0.85)")
        h_cpu, r_cpu = min(x["cpu"] for x in harness), min(x["cpu"] for x in raw)
        print(f"  ratio harness/raw in CPU time       {r_cpu / h_cpu:7.3f}   (raw {r_cpu:.2f} s, "
              f"harness {h_cpu:.2f} s)")
        whole_raw, whole_h = r["warmup"] + r["step"], h["warmup"] + h_time
        print(f"  whole job incl. warm-up: raw {whole_raw:.2f} s, harness {whole_h:.2f} s, ratio "
              f"{whole_raw / whole_h:.3f}")

        # 2. scaling of the local process pool
        seeds = list(range(args.seeds))
        walls = {}
        for workers in (1, 2):
            s = generate(spec, seeds, Path(tmp) / f"w{workers}", workers=workers, progress=False)
            if s["failed"]:
                sys.exit(f"generation failed: {s['failed']}")
            walls[workers] = s["seconds"]
            print(f"  generate {len(seeds)} scenes, {workers} worker(s): {s['seconds']:7.2f} s  "
                  f"{s['agent_frames_per_s']:10,.0f} agent-frames/s")
        same = all((Path(tmp) / "w1" / f).read_bytes() == (Path(tmp) / "w2" / f).read_bytes()
                   for f in ["_manifest.json", *(f"scene-{s:06d}.parquet" for s in seeds)])
        print(f"  speed-up 2 workers / 1 worker       {walls[1] / walls[2]:7.3f}   (target >= 1.7); "
              f"data sets byte-identical: {same}")
        print(f"  machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end (other work on "
              f"the same cores skews both figures)")


if __name__ == "__main__":
    main()
