"""Executors on real Ray (one local instance, 2 CPUs, shared by the module) and the local process pool.

Same data set whatever the executor and the number of workers; a job whose process is killed is run
again and the data set is whole and identical; a job that always dies is reported by seed while the
others land, and a rerun finishes only what is missing. The local pool reuses its worker processes,
but never after a failed job nor after a job that left a SUMO simulation open, and reuse changes no
result; a worker dying mid-run fails `simharness sensitivity` with one line naming the episode.
Faults are injected by job classes defined here (workers import this module by name), never by
mocking the executors, Ray or SUMO.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from simharness import generation
from simharness.errors import SimulatorError, UserError
from simharness.executors import Executor, LocalExecutor, RayExecutor, make_executor, start_local_ray
from simharness.generation import SceneJob, generate
from simharness.io.parquet import TMP_PREFIX, read_manifest
from simharness.scenario import load_scenario

SEEDS = [0, 1, 2]


@pytest.fixture(scope="module")
def ray_instance():
    """One local Ray instance (2 CPUs) for the module: executors join it and leave it running."""
    import ray  # the optional extra simharness[ray] (the dev extra installs it); workers never need it here

    start_local_ray(2, object_store_memory=200 * 2**20)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def spec():
    """The shipped dense arterial, short: 10 s warm-up, 4 s recorded (about a second per scene)."""
    return load_scenario("sumo_arterial_dense").with_overrides({"warmup": 10.0, "duration": 4.0})


def dataset_bytes(folder: Path) -> dict[str, bytes]:
    """Every file of a data set (shards and manifest); the run log is run details, not data."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.name not in ("_runs.jsonl", "_lock")}


@pytest.fixture(scope="module")
def reference(spec, tmp_path_factory) -> dict[str, bytes]:
    """The data set of SEEDS from the local pool with one worker."""
    out = tmp_path_factory.mktemp("reference") / "ds"
    s = generate(spec, SEEDS, out, workers=1, executor="local", progress=False)
    assert s["done"] == len(SEEDS) and not s["failed"], s
    return dataset_bytes(out)


# ---------------------------------------------------------------------- fault-injecting job functions
@dataclasses.dataclass(frozen=True)
class KilledOnFirstTry(SceneJob):
    """Seed 1 starts its simulator, leaves half a shard and SIGKILLs its own process on its first try."""

    def __call__(self, seed: int):
        marker = self.out.parent / f"killed-seed{seed}"
        if seed == 1 and not marker.exists():
            from simharness.sim import make_simulator

            marker.touch()
            sim = make_simulator(self.spec)
            sim.reset(seed)
            sim.step()
            (self.out / f"{TMP_PREFIX}scene-{seed:06d}.parquet.half").write_bytes(b"PAR1 half a shard")
            os.kill(os.getpid(), signal.SIGKILL)
        return super().__call__(seed)


@dataclasses.dataclass(frozen=True)
class AlwaysKilled(SceneJob):
    """Seed 2's process dies every time (counted in a file: one line per attempt)."""

    def __call__(self, seed: int):
        if seed == 2:
            with open(self.out.parent / "attempts-seed2", "a") as f:
                f.write("x\n")
            os._exit(11)
        return super().__call__(seed)


def flaky(job: tuple[str, Path]):
    """Small jobs for the retry policy: ok, a bug, a simulator crash, a dead process."""
    kind, folder = job
    with open(folder / f"{kind}.attempts", "a") as f:
        f.write("x\n")
    if kind == "bug":
        raise ValueError("a bug is not retried")
    if kind == "bad-input":
        raise UserError("bad input is not retried")
    if kind == "sim":
        raise SimulatorError("simulator crashed")
    if kind == "die":
        os._exit(3)
    return os.getpid()


def _sumo_job(job: tuple[int, bool]) -> int:
    """Start SUMO for seed job[0], step once, close it unless job[1] says to leave it open; -> the process id."""
    from simharness.sim.sumo.simulator import SumoSimulator

    seed, leave_open = job
    sim = SumoSimulator(load_scenario("sumo_arterial_dense").with_overrides({"warmup": 1.0, "duration": 1.0}))
    sim.reset(seed)
    sim.step()
    if not leave_open:
        sim.close()
    return os.getpid()


def _episode_scores(job):  # noqa: ANN001, ANN202 - an EpisodeJob -> its scores without timings
    from simharness.closedloop import run_episode

    scores = run_episode(job)["scores"]
    timing = ("wall_s", "cpu_s", "realtime_factor", "realtime_factor_with_warmup")
    return {k: v for k, v in scores.items() if k not in timing and not k.startswith("time_")}


def _dies_on_seed_1(job):  # noqa: ANN001, ANN202 - the sensitivity job function, killed mid-episode on seed 1
    if job.seed == 1:
        os._exit(9)
    from simharness.closedloop.sensitivity import run_scores

    return run_scores(job)


def executor(name: str, workers: int = 2) -> Executor:
    return make_executor(name, workers)


# ---------------------------------------------------------------------- tests
def test_make_executor_ray_and_its_errors(monkeypatch) -> None:
    pool = make_executor("ray", 3, address="auto")
    assert isinstance(pool, RayExecutor) and isinstance(pool, Executor) and pool.workers == 3
    assert pool.address == "auto" and pool.max_retries == 2
    with pytest.raises(UserError, match="only used with --executor ray"):
        make_executor("local", 2, address="auto")
    with pytest.raises(UserError, match="positive"):
        make_executor("ray", 0)
    with pytest.raises(UserError, match="no Ray cluster answers there"):  # in seconds, not ray.init's minutes
        make_executor("ray", 2, address="127.0.0.1:1")
    with pytest.raises(UserError, match="expected HOST:PORT"):
        make_executor("ray", 2, address="nowhere")
    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` meets where the extra is not installed
    with pytest.raises(UserError, match=r"pip install 'simharness\[ray\]'"):
        make_executor("ray", 2)


def test_embedded_default_never_imports_ray() -> None:
    code = ("import sys, math; from simharness import cli, generation, closedloop, sweep; "
            "from simharness.executors import make_executor; "
            "print(list(make_executor('local', 1).map_unordered(math.sqrt, [4.0]))[0].value, 'ray' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["2.0", "False"]


@pytest.mark.parametrize("name", ["local", "ray"])
def test_retry_policy_is_the_same_on_both_executors(name, ray_instance, tmp_path: Path) -> None:
    kinds = ["ok", "bug", "bad-input", "sim", "die"]
    results = {r.job[0]: r for r in executor(name).map_unordered(flaky, [(k, tmp_path) for k in kinds])}
    attempts = {k: len((tmp_path / f"{k}.attempts").read_text().split()) for k in kinds}
    # A dead process and a simulator crash are run again (2 retries); a bug or bad input never.
    assert attempts == {"ok": 1, "bug": 1, "bad-input": 1, "sim": 3, "die": 3}
    assert {k: r.attempts for k, r in results.items()} == attempts
    assert results["ok"].ok and results["ok"].value != os.getpid()
    assert results["bug"].error == "ValueError: a bug is not retried" and "in flaky" in results["bug"].traceback
    assert results["bad-input"].error == "UserError: bad input is not retried"
    assert results["sim"].error == "SimulatorError: simulator crashed"
    assert results["die"].error.startswith("worker process died")


def test_ray_task_runs_each_job_in_a_fresh_process(ray_instance) -> None:
    pids = [r.value for r in RayExecutor(2).map_unordered(_pid, range(4))]
    assert len(set(pids)) == 4 and os.getpid() not in pids  # max_calls=1: one job per worker process


def _pid(_: int) -> int:
    return os.getpid()


def test_ray_writes_the_same_data_set_as_the_local_pool(spec, reference, ray_instance, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    s = generate(spec, SEEDS, out, workers=2, executor="ray", progress=False)
    assert s["done"] == len(SEEDS) and not s["failed"], s
    got = dataset_bytes(out)
    assert sorted(got) == ["_manifest.json", "scene-000000.parquet", "scene-000001.parquet", "scene-000002.parquet"]
    assert got == reference  # shards and manifest byte for byte: 2 Ray workers vs 1 local process


@pytest.mark.parametrize("name", ["ray", "local"])
def test_killed_simulator_is_retried_and_data_set_is_whole(name, spec, reference, ray_instance, tmp_path: Path,
                                                          monkeypatch) -> None:
    monkeypatch.setattr(generation, "SceneJob", KilledOnFirstTry)
    out = tmp_path / "ds"
    s = generate(spec, SEEDS, out, workers=2, executor=name, progress=False)
    assert (tmp_path / "killed-seed1").exists()  # the first try really died
    assert s["done"] == len(SEEDS) and not s["failed"], s
    assert dataset_bytes(out) == reference  # no partial shard, no duplicate, same bytes
    assert not list(out.glob(TMP_PREFIX + "*"))


@pytest.mark.parametrize("name", ["ray", "local"])
def test_always_dying_job_is_reported_by_seed_and_rerun_finishes_it(name, spec, reference, ray_instance,
                                                                    tmp_path: Path, monkeypatch) -> None:
    out = tmp_path / "ds"
    with monkeypatch.context() as m:
        m.setattr(generation, "SceneJob", AlwaysKilled)
        s = generate(spec, SEEDS, out, workers=2, executor=name, progress=False)
    assert list(s["failed"]) == [2] and s["failed"][2].startswith("worker process died")
    assert "after 3 attempts" in s["failed"][2]
    assert len((tmp_path / "attempts-seed2").read_text().split()) == 3  # 1 try + max_retries, then given up
    assert s["done"] == 2 and read_manifest(out)["info"]["seeds"] == [0, 1]
    assert sorted(p.name for p in out.glob("scene-*")) == ["scene-000000.parquet", "scene-000001.parquet"]
    again = generate(spec, SEEDS, out, workers=2, executor=name, progress=False)
    assert again["skipped"] == 2 and again["done"] == 1 and not again["failed"]  # only the missing seed runs
    assert dataset_bytes(out) == reference


def test_cli_generate_on_its_own_ray_instance(tmp_path: Path) -> None:
    """The CLI path end to end on its own Ray instance (started and stopped by the command)."""
    scenario = tmp_path / "bad.toml"
    text = (Path(load_scenario("sumo_arterial_dense").path).read_text()
            .replace("duration = 60.0", "duration = 2.0").replace("warmup = 90.0", "warmup = 5.0"))
    scenario.write_text(text)
    out = tmp_path / "ds"
    run = subprocess.run([sys.executable, "-m", "simharness", "generate", str(scenario), "--seeds", "0-1", "--out",
                          str(out), "--executor", "ray", "--workers", "2"], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "2 scenes generated" in run.stdout
    assert read_manifest(out)["num_scenes"] == 2


def test_local_pool_reuses_workers_up_to_jobs_per_worker(tmp_path: Path) -> None:
    one = [r.value for r in LocalExecutor(1).map_unordered(_pid, range(5))]
    assert len(set(one)) == 1 and os.getpid() not in one  # one long-lived worker ran all five
    fresh = [r.value for r in LocalExecutor(2, jobs_per_worker=1).map_unordered(_pid, range(4))]
    assert len(set(fresh)) == 4  # the former behaviour: a process per job
    pairs = [r.value for r in LocalExecutor(1, jobs_per_worker=2).map_unordered(_pid, range(5))]
    assert [len(set(pairs[i:i + 2])) for i in (0, 2, 4)] == [1, 1, 1] and len(set(pairs)) == 3
    # A failed job's worker is not reused: the job after it (and each retry) starts a fresh process.
    kinds = ["ok", "bug", "ok2", "sim", "ok3"]
    res = list(LocalExecutor(1, max_retries=1).map_unordered(flaky, [(k, tmp_path) for k in kinds]))
    assert [r.job[0] for r in res] == ["ok", "bug", "ok2", "sim", "ok3"]  # one worker: the order is kept
    assert res[0].ok and not res[1].ok and res[2].ok and not res[3].ok and res[4].ok and res[3].attempts == 2
    assert res[2].value != res[0].value and res[4].value != res[2].value
    with pytest.raises(UserError, match="jobs_per_worker"):
        LocalExecutor(1, jobs_per_worker=0)


def test_reused_worker_closes_what_a_job_left_open_and_sumo_runs_again() -> None:
    """libsumo allows one simulation per process: jobs that close theirs share a worker; one that leaves its
    simulation open gets it closed and its worker retired, and the next SUMO job still starts."""
    res = list(LocalExecutor(1).map_unordered(_sumo_job, [(0, False), (1, False), (2, True), (3, False)]))
    assert all(r.ok for r in res), [r.error for r in res]
    pids = [r.value for r in res]
    assert pids[0] == pids[1] == pids[2] and pids[3] != pids[2]


def test_reused_workers_give_the_same_episodes_as_fresh_processes() -> None:
    from simharness.closedloop import EpisodeJob, prepare_spec

    spec = prepare_spec(load_scenario("highway_mixed_dense"), "cut_in").with_overrides(
        {"duration": 6.0, "warmup": 5.0, "ego.insert_at": 2.0})
    jobs = [EpisodeJob(spec, s, "const-vel", keep_scene=False) for s in (0, 1, 2)]
    reused = {r.job.seed: r.value for r in LocalExecutor(1).map_unordered(_episode_scores, jobs)}
    fresh = {r.job.seed: r.value for r in LocalExecutor(2, jobs_per_worker=1).map_unordered(_episode_scores, jobs)}
    assert reused == fresh and len({json.dumps(v, sort_keys=True, default=str) for v in reused.values()}) == 3


def test_sensitivity_worker_death_is_one_line_naming_the_episode(tmp_path: Path, monkeypatch, capsys) -> None:
    from simharness.cli import main
    from simharness.closedloop import sensitivity

    monkeypatch.setattr(sensitivity, "run_scores", _dies_on_seed_1)
    scenario = tmp_path / "short.toml"
    from simharness.scenario import SCENARIO_DIR

    text = (SCENARIO_DIR / "stress" / "step_out.toml").read_text()
    scenario.write_text(text.replace("duration = 15.0", "duration = 2.0").replace("warmup = 20.0", "warmup = 2.0"))
    out = tmp_path / "sens"
    rc = main(["sensitivity", str(scenario), "--predictor", "const-vel", "--perturb", "noise=0", "--seeds", "0-1",
               "--workers", "1", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    lines = [ln for ln in err if "failed" in ln]
    assert len(lines) == 1 and "none seed 1: worker process died (exit code 9)" in lines[0], err
    assert not (out / "sensitivity.json").exists() and not (out / "sensitivity.md").exists()
