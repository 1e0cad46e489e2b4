"""Run many independent jobs (one (scenario, seed) each): the seam between job functions and pools.

A job function takes one picklable job and returns a picklable value; it knows nothing of the
pool. An `Executor` maps it over jobs and streams `JobResult`s back as they finish, in any order.
A job whose process dies, or that raises one of `retry_on` (a simulator crash), is run again in a
fresh process, at most `max_retries` more times; then, like a job that raises anything else (a bug,
bad input), it comes back as a failed result while the others go on. Both executors share this
policy, so a run behaves alike on either.

`LocalExecutor` keeps up to `workers` spawned worker processes for the whole run and sends each
one job after another (at most `jobs_per_worker` each, then a fresh one takes its place), so that
many short jobs pay Python, torch and scenario imports once per worker, not once per job. A worker
is never reused after its job failed (the retry, or the next job, gets a fresh process) nor when
its job left a SUMO simulation open (libsumo allows one per process: such a job's simulation is
closed and its worker retired). `jobs_per_worker=1` is a fresh process per job.
`RayExecutor` runs every job as a Ray task in a worker process used once (`max_calls=1`), on a
local Ray instance it starts (and stops) or on a cluster at `address`; Ray is an optional extra,
imported only here and only when asked for.
"""

from __future__ import annotations

import dataclasses
import logging
import multiprocessing as mp
import os
import re
import socket
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection, wait
from typing import Any, Protocol, runtime_checkable

from simharness.errors import SimulatorError, UserError

RETRY_ON: tuple[type[BaseException], ...] = (SimulatorError,)  # a simulator crash may not recur; a bug will
MAX_RETRIES = 2


@dataclasses.dataclass(frozen=True)
class JobResult:
    """What came back for one job: its value, or one line of error text (and the traceback)."""

    job: Any
    value: Any = None
    error: str | None = None
    traceback: str = ""
    attempts: int = 1  # how many times the job ran (1 + retries)

    @property
    def ok(self) -> bool:
        return self.error is None


@runtime_checkable
class Executor(Protocol):
    """Maps a job function over jobs; results stream back in completion order."""

    workers: int

    def map_unordered(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[JobResult]: ...


def _one_line(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}".strip().splitlines()[0]


def log_retry(job: Any, attempt: int, max_retries: int, error: str | None) -> None:
    """One stderr line per retried job: a killed worker or a simulator crash is never retried silently."""
    if hasattr(job, "seed"):  # an episode: its predictor and seed name it
        label = " ".join(str(x) for x in (getattr(job, "predictor", None), f"seed {job.seed}") if x)
    else:
        text = repr(job)
        label = f"job {text if len(text) <= 80 else text[:77] + '...'}"
    print(f"simharness: {label}: attempt {attempt} of {max_retries + 1} ended ({error}); retrying in a fresh process",
          file=sys.stderr, flush=True)


def _check_policy(workers: int, max_retries: int) -> None:
    if workers < 1:
        raise UserError(f"--workers: expected a positive number of processes, got {workers}")
    if max_retries < 0:
        raise UserError(f"max_retries: expected 0 or more, got {max_retries}")


def _release_simulators() -> bool:
    """Close any SUMO simulation a job left open in this process -> whether none was (the process is clean)."""
    sumo = sys.modules.get("simharness.sim.sumo.simulator")
    live = list(getattr(sumo, "_LIVE", ()))
    for sim in live:
        sim.close()
    return not live


def _worker(fn: Callable[[Any], Any], conn: Connection, retry_on: tuple[type[BaseException], ...] = RETRY_ON) -> None:
    """Body of a worker process: run the jobs it is sent until it is sent None or the parent closes the pipe (it
    retires a worker by closing it); for each send ("ok", value, reusable) or ("error", line, traceback,
    retryable). It stops after a failed job, and after a job that left a simulation open (`reusable` False)."""
    try:
        while True:
            try:
                job = conn.recv()
            except EOFError:  # the parent is gone, or retired this worker
                return
            if job is None:
                return
            try:
                value = fn(job)
            except BaseException as e:  # noqa: B036 - a job's KeyboardInterrupt is reported too
                conn.send(("error", _one_line(e), traceback.format_exc(), isinstance(e, retry_on)))
                return
            reusable = _release_simulators()
            conn.send(("ok", value, reusable))
            if not reusable:
                return
    finally:
        conn.close()


@dataclasses.dataclass
class _Worker:
    """A worker process, its end of the pipe, the job it runs (with its attempt) and the jobs it has left."""

    proc: Any
    conn: Connection
    left: int | None
    job: Any = None
    attempt: int = 0


class LocalExecutor:
    """Up to `workers` spawn-context worker processes on this machine, each reused for up to `jobs_per_worker`
    jobs (None: no limit; 1: a fresh process per job)."""

    def __init__(self, workers: int = 2, max_retries: int = MAX_RETRIES,
                 retry_on: tuple[type[BaseException], ...] = RETRY_ON, jobs_per_worker: int | None = 100) -> None:
        _check_policy(workers, max_retries)
        if jobs_per_worker is not None and jobs_per_worker < 1:
            raise UserError(f"jobs_per_worker: expected a positive number or None, got {jobs_per_worker}")
        self.workers = int(workers)
        self.max_retries = int(max_retries)
        self.retry_on = tuple(retry_on)
        self.jobs_per_worker = jobs_per_worker
        self._ctx = mp.get_context("spawn")

    def _start(self, fn: Callable[[Any], Any]) -> _Worker:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=_worker, args=(fn, child, self.retry_on), daemon=True)
        proc.start()
        child.close()  # the worker holds the only other end: EOF here means it died
        return _Worker(proc, parent, self.jobs_per_worker)

    def map_unordered(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[JobResult]:
        pending = [(job, 1) for job in reversed(list(jobs))]  # pop() from the end keeps the given order
        idle: list[_Worker] = []
        busy: dict[Connection, _Worker] = {}
        try:
            while pending or busy:
                while pending and len(busy) < self.workers:
                    w = idle.pop() if idle else self._start(fn)
                    w.job, w.attempt = pending.pop()
                    try:
                        w.conn.send(w.job)
                    except OSError:  # died before its first job (it could not start): EOF comes at once
                        pass
                    busy[w.conn] = w
                for conn in wait(list(busy)):
                    w = busy.pop(conn)
                    result, retryable, reusable = self._collect(w)
                    if reusable:
                        idle.append(w)
                    if retryable and w.attempt <= self.max_retries:
                        log_retry(w.job, w.attempt, self.max_retries, result.error)
                        pending.append((w.job, w.attempt + 1))  # next to start: a retry keeps its place in line
                    else:
                        yield dataclasses.replace(result, attempts=w.attempt)
        finally:
            for w in idle:  # done: idle workers stop when told
                self._stop(w, ask=True)
            for w in busy.values():  # interrupted: stop what still runs
                self._stop(w, ask=False)

    @staticmethod
    def _stop(w: _Worker, ask: bool) -> None:
        if ask:
            try:
                w.conn.send(None)
            except OSError:
                pass
            w.proc.join(5)
        if w.proc.is_alive():
            w.proc.terminate()
            w.proc.join(5)
        w.conn.close()

    @staticmethod
    def _collect(w: _Worker) -> tuple[JobResult, bool, bool]:
        """The job's result, whether running it again might help (its process died, or it may retry), and
        whether its worker takes another job (otherwise it has exited or is exiting: it is joined here)."""
        try:
            msg = w.conn.recv()
        except (EOFError, OSError):
            msg = None
        reusable = msg is not None and msg[0] == "ok" and msg[2]
        if reusable and w.left is not None:
            w.left -= 1
            reusable = w.left > 0
        if not reusable:
            w.conn.close()
            w.proc.join()
        if msg is None:
            return JobResult(w.job, error=f"worker process died (exit code {w.proc.exitcode})"), True, False
        if msg[0] == "ok":
            return JobResult(w.job, value=msg[1]), False, reusable
        return JobResult(w.job, error=msg[1], traceback=msg[2]), msg[3], False


# ---------------------------------------------------------------------- Ray
def import_ray() -> Any:
    """The `ray` module, or a UserError saying how to install it (it is an optional extra)."""
    try:
        import ray
    except ImportError:
        raise UserError("--executor ray: Ray is not installed; install it with: pip install 'simharness[ray]'"
                        ) from None
    return ray


def _ray_task(fn: Callable[[Any], Any], job: Any) -> Any:
    """Body of one Ray task; it runs in a worker process that exits after it (max_calls=1)."""
    return fn(job)


class RayExecutor:
    """One Ray task per job (and per retry), each in a worker process used once, at most `workers` at once.

    With no `address` (and no Ray already initialised in this process) it starts a local Ray instance
    with `num_cpus=workers` and no dashboard, and shuts it down after each `map_unordered`. With an
    `address` ("auto": RAY_ADDRESS or the cluster `ray start` made here; "ray://host:10001";
    "host:6379") it joins that cluster and leaves it running;
    every node must have simharness installed and see the same paths (data set folder, run folders).
    Retries are counted here, not by Ray (its `max_retries=0`), so attempts are reported as locally.
    """

    def __init__(self, workers: int = 2, address: str | None = None, max_retries: int = MAX_RETRIES,
                 retry_on: tuple[type[BaseException], ...] = RETRY_ON, object_store_memory: int | None = None
                 ) -> None:
        _check_policy(workers, max_retries)
        self.workers = int(workers)
        self.address = address or None
        self.max_retries = int(max_retries)
        self.retry_on = tuple(retry_on)
        self.object_store_memory = object_store_memory
        self.startup_s: float | None = None  # seconds ray.init took in the last run (None: joined a running Ray)

    def map_unordered(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[JobResult]:
        ray = import_ray()
        started = self._connect(ray)
        try:
            task = ray.remote(num_cpus=1, max_calls=1, max_retries=0)(_ray_task)
            fn_ref = ray.put(fn)  # shipped once, not with every job
            pending = [(job, 1) for job in reversed(list(jobs))]
            running: dict[Any, tuple[Any, int]] = {}  # ObjectRef -> (job, attempt)
            try:
                while pending or running:
                    while pending and len(running) < self.workers:
                        job, attempt = pending.pop()
                        running[task.remote(fn_ref, job)] = (job, attempt)
                    done, _ = ray.wait(list(running), num_returns=1)
                    for ref in done:
                        job, attempt = running.pop(ref)
                        result, retryable = self._collect(ray, ref, job)
                        if retryable and attempt <= self.max_retries:
                            log_retry(job, attempt, self.max_retries, result.error)
                            pending.append((job, attempt + 1))
                        else:
                            yield dataclasses.replace(result, attempts=attempt)
            finally:
                for ref in running:  # interrupted: stop what still runs
                    ray.cancel(ref, force=True)
        finally:
            if started:
                ray.shutdown()

    def _collect(self, ray: Any, ref: Any, job: Any) -> tuple[JobResult, bool]:
        try:
            return JobResult(job, value=ray.get(ref)), False
        except ray.exceptions.RayTaskError as e:  # the job raised: Ray re-raises it wrapped
            cause = e.cause if isinstance(e.cause, BaseException) else e
            tb = re.sub(r"\x1b\[[0-9;]*m", "", getattr(e, "traceback_str", "") or str(e))  # no colour codes
            return JobResult(job, error=_one_line(cause), traceback=tb), isinstance(cause, self.retry_on)
        except ray.exceptions.TaskCancelledError as e:
            return JobResult(job, error=f"cancelled ({type(e).__name__})"), False
        except ray.exceptions.RayError as e:  # worker crashed, killed for memory, node lost, object lost
            detail = str(e).strip().splitlines()[0] if str(e).strip() else ""
            return JobResult(job, error=f"worker process died ({type(e).__name__}: {detail})"), True

    def _connect(self, ray: Any) -> bool:
        """Join a running Ray, or start a local instance; True when we started one (and must stop it)."""
        if ray.is_initialized():
            self.startup_s = None
            return False
        if self.address:
            _probe(self.address)
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
            t0 = time.perf_counter()
            try:
                ray.init(address=self.address, logging_level=logging.ERROR, log_to_driver=False)
            except (ConnectionError, ValueError, RuntimeError) as e:
                why = _one_line(e.__cause__ or e)  # Ray's ConnectionError hides the reason (e.g. authentication)
                raise UserError(f"--address {self.address}: cannot join a Ray cluster there: {why}") from None
            self.startup_s = time.perf_counter() - t0
            return True  # our connection only: shutdown() disconnects, the cluster keeps running
        self.startup_s = start_local_ray(self.workers, self.object_store_memory)
        return True


def _probe(address: str, timeout: float = 5.0) -> None:
    """Fail in seconds, with one line, where nothing listens at a host:port address (ray.init waits minutes)."""
    if address in ("auto", "local"):
        return
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise UserError(f"--address {address}: expected HOST:PORT, ray://HOST:PORT or auto")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as e:
        raise UserError(f"--address {address}: no Ray cluster answers there ({e.strerror or e}); start one with "
                        "`ray start --head` or check the address") from None


def start_local_ray(cpus: int, object_store_memory: int | None = None) -> float:
    """Start a quiet local Ray instance with `cpus` CPUs and no dashboard; returns the seconds it took.

    Its workers import what this process can import (its sys.path), as spawned processes would.
    """
    ray = import_ray()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage-stats prompt or upload
    saved = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)  # inherited by the raylet's workers
    t0 = time.perf_counter()
    try:
        # address="local": always a new instance, never a `ray start` cluster or RAY_ADDRESS found by chance.
        ray.init(address="local", num_cpus=cpus, include_dashboard=False, object_store_memory=object_store_memory,
                 logging_level=logging.ERROR, log_to_driver=False)
    finally:
        if saved is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved
    return time.perf_counter() - t0


def make_executor(name: str = "local", workers: int = 2, address: str | None = None,
                  max_retries: int = MAX_RETRIES) -> Executor:
    """The executor named on the command line: 'local' (process pool) or 'ray' (local instance or cluster)."""
    if name == "local":
        if address:
            raise UserError("--address: only used with --executor ray")
        return LocalExecutor(workers, max_retries=max_retries)
    if name == "ray":
        import_ray()  # fail now, before any work, when the extra is missing
        if address:
            _probe(address)  # and when nothing listens at the address
        return RayExecutor(workers, address, max_retries=max_retries)
    raise UserError(f"--executor: unknown executor {name!r}; expected local or ray")
