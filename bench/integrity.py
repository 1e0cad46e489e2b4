"""What shard integrity costs: sha256 per shard, opening a data set with and without verification, reading it,
and the resume check of `generate` (listed shards vs shards a killed run left unlisted).

    .venv/bin/python bench/integrity.py [--scenes 40] [--agents 200] [--frames 300]

Shards are written through the real Parquet layer from synthetic scenes of the size of a dense SUMO scene
(200 agents x 300 frames = 60 s at 5 Hz). Every figure is a median over repeats, measured in one run.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from simharness.generation import _existing_entries
from simharness.io.parquet import Dataset, build_manifest, file_sha256, read_manifest, write_dataset, write_manifest
from simharness.scenario import load_scenario
from simharness.scene import AgentType, Scene


def dense_scene(seed: int, n: int, t: int, config_hash: str, dt: float = 0.2) -> Scene:
    rng = np.random.default_rng(seed)
    speed = rng.uniform(1, 14, (n, 1)) + rng.normal(0, 0.3, (n, t))
    xy = np.stack([rng.uniform(0, 500, (n, 1)) + np.cumsum(speed * dt, 1), rng.uniform(-5, 5, (n, t))], -1)
    valid = np.arange(t)[None] >= rng.integers(0, t // 2, (n, 1))
    types = rng.integers(0, len(AgentType), n)
    fp = np.array([AgentType(int(k)).footprint for k in types])
    return Scene(xy=xy * valid[..., None], heading=np.zeros((n, t)), speed=speed * valid, valid=valid,
                 agent_id=[f"a{i}" for i in range(n)], agent_type=types, length=fp[:, 0], width=fp[:, 1], dt=dt,
                 meta={"scene_id": f"scene-{seed:06d}", "seed": seed, "config_hash": config_hash})


def median_s(fn: Callable[[], object], repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=40)
    ap.add_argument("--agents", type=int, default=200)
    ap.add_argument("--frames", type=int, default=300)
    args = ap.parse_args()
    spec = load_scenario("sumo_arterial_dense")
    with tempfile.TemporaryDirectory() as tmp:
        scenes = (dense_scene(s, args.agents, args.frames, spec.config_hash()) for s in range(args.scenes))
        out = write_dataset(scenes, Path(tmp) / "ds", {"source": "bench/integrity.py",
                                                       "config_hash": spec.config_hash()})
        shards = sorted(out.glob("*.parquet"))
        mb = sum(p.stat().st_size for p in shards) / 1e6
        n = len(shards)
        print(f"{n} shards, {mb / n:.2f} MB each ({mb:.1f} MB), {read_manifest(out)['rows'] // n:,} rows each")
        sha = median_s(lambda: [file_sha256(p) for p in shards])
        print(f"  sha256 of one shard                 {1e3 * sha / n:8.3f} ms  ({mb / sha:,.0f} MB/s)")
        open_v = median_s(lambda: Dataset(out))
        open_nv = median_s(lambda: Dataset(out, verify=False))
        print(f"  open, size + sha256 checked          {1e3 * open_v / n:8.3f} ms per shard")
        print(f"  open, size checked only              {1e3 * open_nv / n:8.3f} ms per shard")
        read = median_s(lambda: list(Dataset(out, verify=False)), repeats=3)
        print(f"  reading every scene                  {1e3 * read / n:8.3f} ms per shard")
        print(f"  verification / (open + read)         {100 * (open_v - open_nv) / (open_nv + read):8.1f} %")
        # resume check: every shard listed (size + sha256) vs none listed (footer + metadata + sha256)
        listed = median_s(lambda: _existing_entries(spec, out, []), repeats=3)
        write_manifest(out, build_manifest([], read_manifest(out)["info"]))  # as a kill -9 can leave it
        unlisted = median_s(lambda: _existing_entries(spec, out, []), repeats=3)
        print(f"  resume check, shard listed           {1e3 * listed / n:8.3f} ms per shard")
        print(f"  resume check, shard unlisted         {1e3 * unlisted / n:8.3f} ms per shard (footer read)")


if __name__ == "__main__":
    main()
