"""`simharness generate`: simulate a scenario over seeds into a Parquet data set.

The job function `generate_scene` (one seed -> one shard) is separate from the pool: `generate`
hands it to any `Executor` (local processes now, a cluster later). A run can be interrupted at any
point: shards appear only when complete (temporary name, then rename), the manifest is refreshed
every few seconds and at the end (Ctrl-C included), and a rerun cleans temporary leftovers, checks every
shard against the manifest (size, sha256), remakes damaged ones, lists complete ones a killed run left
unlisted, and runs only the missing seeds. A shard is removed only when its own bytes show it damaged
(`parquet.shard_damage`); a manifest entry that disagrees with an intact shard is repaired. One writer at a
time per folder (`folders.writer_lock`); a run refused up front leaves the folder as it was.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import re
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from simharness.errors import SimulatorError, UserError
from simharness.executors import make_executor
from simharness.io.folders import (
    LOCK,
    check_writable,
    make_folder,
    open_append,
    refuse_inside_dataset,
    refuse_symlinks,
    writer_lock,
)
from simharness.io.parquet import (
    LEGACY_MANIFEST,
    MANIFEST,
    TMP_PREFIX,
    build_manifest,
    clean_temp_files,
    describe_shard,
    manifest_path,
    read_manifest,
    shard_damage,
    shard_problem,
    software_versions,
    write_manifest,
    write_scene,
)
from simharness.scenario import ScenarioSpec, load_scenario

SOURCE = "simharness generate"
RUN_LOG = "_runs.jsonl"
LEGACY_RUN_LOG = "runs.jsonl"  # before 0.1.1; renamed to RUN_LOG on the next run
SHARD_NAME = re.compile(r"scene-(\d{6,})\.parquet")


def shard_path(out: Path, seed: int) -> Path:
    return Path(out) / f"scene-{seed:06d}.parquet"


def _check_shard(entry: dict[str, Any], spec: ScenarioSpec, path: Path) -> None:
    got = entry["meta"].get("config_hash")
    if got != spec.config_hash():
        raise UserError(f"{path}: shard of scenario {entry['meta'].get('scenario')!r} (config {got}); refusing to "
                        f"mix it with {spec.name!r} (config {spec.config_hash()}): choose another --out")


def generate_scene(spec: ScenarioSpec, seed: int, out: Path) -> dict[str, Any]:
    """Simulate one seed and write its shard `scene-{seed:06d}.parquet` atomically; skip if complete.

    Returns the shard's manifest entry plus {seed, agent_frames, collisions, teleports, seconds, skipped}
    (collisions and teleports as the simulator reported them; seconds of wall time, warm-up included).
    """
    from simharness.sim import make_simulator, scene_from_frames

    path = shard_path(out, seed)
    if path.exists():  # only complete shards carry the final name
        entry = describe_shard(path)
        _check_shard(entry, spec, path)
        return {**entry, "seed": seed, "agent_frames": entry["rows"], "collisions": _count(entry, "collision"),
                "teleports": _count(entry, "teleport"), "seconds": 0.0, "skipped": True}
    start = time.perf_counter()
    sim = make_simulator(spec)
    try:
        frames = [sim.reset(seed)]  # the backend adds spec.seed (the scenario's base seed)
        frames += [sim.step() for _ in range(spec.num_frames - 1)]
        road = sim.road
    except UserError:
        raise
    except Exception as e:
        raise SimulatorError(f"{spec.name} seed {seed}: {type(e).__name__}: {e}") from e
    finally:
        sim.close()
    scene_id = path.stem
    meta = {
        "source": SOURCE, "scene_id": scene_id, "scenario": spec.name, "backend": spec.backend, "seed": seed,
        "base_seed": spec.seed, "sim_seed": spec.sim_seed(seed), "config_hash": spec.config_hash(), "units": "m",
        "road": road.to_dict() if road is not None else None, "versions": software_versions(),
    }
    scene = scene_from_frames(frames, spec.dt, meta)
    rows = write_scene(scene, path, scene_id)
    entry = describe_shard(path)
    assert entry["rows"] == rows
    return {**entry, "seed": seed, "agent_frames": rows, "collisions": _count(entry, "collision"),
            "teleports": _count(entry, "teleport"), "seconds": time.perf_counter() - start, "skipped": False}


def _count(entry: dict[str, Any], kind: str) -> int:
    return sum(e.get("kind") == kind for e in entry["meta"].get("events", []))


@dataclasses.dataclass(frozen=True)
class SceneJob:
    """Picklable job function for executors: seed -> `generate_scene(spec, seed, out)`."""

    spec: ScenarioSpec
    out: Path

    def __call__(self, seed: int) -> dict[str, Any]:
        return generate_scene(self.spec, seed, self.out)


def dataset_info(spec: ScenarioSpec, seeds: Sequence[int]) -> dict[str, Any]:
    """The manifest's `info`: a function of the scenario and the shards present only (no run details)."""
    return {"source": SOURCE, "scenario": spec.name, "backend": spec.backend, "config_hash": spec.config_hash(),
            "base_seed": spec.seed, "seeds": sorted(int(s) for s in seeds), "spec": spec.to_dict()}


def _refuse_foreign(spec: ScenarioSpec, out: Path) -> dict[str, dict[str, Any]]:
    """Manifest entries by file of the data set in `out`; UserError if `out` holds another scenario's data set,
    a file that is not part of one, or a symbolic link. Writes nothing, so it runs before the lock is taken."""
    known: dict[str, dict[str, Any]] = {}
    refuse_symlinks(out)
    if manifest_path(out).is_file():
        manifest = read_manifest(out)
        info = manifest.get("info", {})
        if info.get("config_hash") != spec.config_hash():
            raise UserError(f"{out}: holds a data set of {info.get('scenario', info.get('source'))!r} (config "
                            f"{info.get('config_hash')}); refusing to mix it with {spec.name!r} (config "
                            f"{spec.config_hash()}): choose another --out")
        known = {e["file"]: e for e in manifest.get("scenes", [])}
    allowed = {MANIFEST, LEGACY_MANIFEST, RUN_LOG, LEGACY_RUN_LOG, LOCK}
    strangers = sorted(p.name for p in out.iterdir() if p.name not in allowed and not p.name.startswith(TMP_PREFIX)
                       and not SHARD_NAME.fullmatch(p.name))
    if strangers:
        raise UserError(f"{out}: holds {strangers[0]!r}, which is not part of a simharness data set; choose an "
                        f"empty or new --out")
    return known


def _existing_entries(spec: ScenarioSpec, out: Path, seeds: Sequence[int]) -> tuple[dict[int, dict[str, Any]],
                                                                                    list[str]]:
    """(complete, intact shards already in `out` by seed, notes for the user); refuses another scenario's folder.

    A listed shard that matches its manifest entry (size, sha256) is taken as is. One that does not, and an
    unlisted one (a run killed before it refreshed the manifest), is judged by its own bytes: intact and of
    this config, it is kept (and a wrong entry repaired); damaged, it is removed, so that this run remakes it
    (or a rerun with its seed does).
    """
    known = _refuse_foreign(spec, out)
    entries, notes, wanted = {}, [], set(seeds)
    for path in sorted(out.glob("scene-*.parquet")):
        if not SHARD_NAME.fullmatch(path.name):
            continue
        seed = int(SHARD_NAME.fullmatch(path.name).group(1))
        entry = known.get(path.name)
        problem = shard_problem(path, entry) if entry is not None else "unlisted"
        if problem:
            listed_problem, problem = problem, shard_damage(path)
            if problem is None:
                described = describe_shard(path)
                _check_shard(described, spec, path)
                if entry is not None:
                    notes.append(f"{path.name}: {listed_problem.split(' (')[0]}, yet the shard reads intact (page "
                                 f"checksums, metadata, rows); its {MANIFEST} entry is repaired")
                entry = {k: v for k, v in described.items() if k != "meta"}
        if problem:
            path.unlink()
            notes.append(f"{path.name}: damaged ({problem}); removed, "
                         + ("remade in this run" if seed in wanted else f"rerun with --seeds {seed} to remake it"))
            continue
        entries[seed] = entry
    return entries, notes


MANIFEST_EVERY_S = 10.0  # how often a running generation refreshes _manifest.json


def generate(spec: ScenarioSpec, seeds: Sequence[int], out: Path, workers: int = 2, executor: str = "local",
             address: str | None = None, progress: bool = True) -> dict[str, Any]:
    """Simulate `seeds` of `spec` into the data set folder `out`; resumable, never mixes scenarios.

    Returns {scenario, config_hash, out, requested, done, skipped, failed: {seed: error}, agent_frames,
    seconds, agent_frames_per_s, collisions, teleports}.
    """
    out = Path(out)
    for seed in seeds:  # the one seed the simulator gets must be a 32-bit signed one
        spec.sim_seed(seed)
    check_writable(out)
    refuse_inside_dataset(out, include_self=False)  # `out` may be this scenario's own data set (a resume)
    pool = make_executor(executor, workers, address)
    if out.is_dir():
        _refuse_foreign(spec, out)  # before the lock: a refused run leaves no `_lock` behind
    make_folder(out)
    with writer_lock(out):
        return _generate_locked(spec, seeds, out, pool, workers, executor, progress)


def _generate_locked(spec: ScenarioSpec, seeds: Sequence[int], out: Path, pool: Any, workers: int, executor: str,
                     progress: bool) -> dict[str, Any]:
    """`generate` once this process holds the folder's writer lock."""
    started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    clean_temp_files(out)  # safe: no other writer runs (the lock)
    entries, notes = _existing_entries(spec, out, seeds)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    todo = [s for s in seeds if s not in entries]
    skipped = len(seeds) - len(todo)

    last_save = 0.0

    def save() -> None:
        nonlocal last_save
        write_manifest(out, build_manifest(entries.values(), dataset_info(spec, entries)))
        last_save = time.perf_counter()

    save()
    failed: dict[int, str] = {}
    agent_frames = collisions = teleports = 0
    sim_seconds = 0.0
    bar = tqdm(total=len(todo), unit="scene", file=sys.stderr, disable=not progress or not todo,
               desc=f"generate {spec.name}", dynamic_ncols=True)
    try:
        # An absolute folder: a cluster's workers do not share this process's working directory.
        for result in pool.map_unordered(SceneJob(spec, out.absolute()), todo):
            if result.ok:
                v = result.value
                entries[result.job] = {k: v[k] for k in ("scene_id", "file", "rows", "agents", "frames", "bytes",
                                                         "sha256")}
                # Readers see progress every few seconds; a resume needs no manifest (shards describe
                # themselves), and rewriting it after every shard would cost O(scenes^2) on big runs.
                if time.perf_counter() - last_save > MANIFEST_EVERY_S:
                    save()
                agent_frames += v["agent_frames"]
                collisions += v["collisions"]
                teleports += v["teleports"]
                sim_seconds += v["seconds"]
            else:
                failed[result.job] = result.error + (f" (after {result.attempts} attempts)" if result.attempts > 1
                                                     else "")
                tqdm.write(f"seed {result.job} failed: {result.error}", file=sys.stderr)
            bar.update(1)
            rate = agent_frames / max(time.perf_counter() - t0, 1e-9)
            bar.set_postfix_str(f"{rate:,.0f} agent-frames/s, {len(failed)} failed")
    finally:
        bar.close()
        save()  # Ctrl-C included: what completed is listed
    clean_temp_files(out)  # half-written files of attempts whose worker died (their retries completed)
    seconds = time.perf_counter() - t0
    summary = {
        "scenario": spec.name, "config_hash": spec.config_hash(), "out": str(out), "requested": len(seeds),
        "done": len(todo) - len(failed), "skipped": skipped, "failed": {int(k): v for k, v in sorted(failed.items())},
        "agent_frames": agent_frames, "seconds": round(seconds, 3), "job_seconds": round(sim_seconds, 3),
        "agent_frames_per_s": round(agent_frames / max(seconds, 1e-9), 1), "collisions": collisions,
        "teleports": teleports, "scenes_in_dataset": len(entries), "remade_or_removed": notes,
    }
    log = {"started_utc": started, "command": sys.argv, "seeds": list(map(int, seeds)), "workers": workers,
           "executor": executor, "versions": software_versions(), **summary}
    if (out / LEGACY_RUN_LOG).is_file() and not (out / RUN_LOG).exists():
        os.replace(out / LEGACY_RUN_LOG, out / RUN_LOG)
    fd = open_append(out, RUN_LOG)  # run details live here, never in shards/manifest; never through a link
    with os.fdopen(fd, "a", encoding="utf-8") as f:
        f.write(json.dumps(log, sort_keys=True) + "\n")
    return summary


def generate_command(args: Any) -> int:
    """CLI: `simharness generate SCENARIO --seeds 0-99 --out DIR --workers K [--duration S]`."""
    spec = load_scenario(args.scenario)
    if args.duration is not None:
        spec = spec.with_overrides({"duration": args.duration})
    s = generate(spec, args.seeds, args.out, args.workers, args.executor, args.address)
    print(f"{s['scenario']}: {s['done']} scenes generated, {s['skipped']} already complete, {len(s['failed'])} "
          f"failed; {s['agent_frames']:,} agent-frames in {s['seconds']:.1f} s ({s['agent_frames_per_s']:,.0f}/s); "
          f"simulator collisions {s['collisions']}, teleports {s['teleports']} -> {s['out']}")
    if s["failed"]:
        seeds = ", ".join(str(k) for k in s["failed"])
        first = next(iter(s["failed"].values()))
        raise SimulatorError(f"seeds {seeds} failed (first: {first}); completed shards are kept, rerun to retry")
    return 0
