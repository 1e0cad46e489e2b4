"""Run many independent jobs (one (scenario, seed) each): the seam between job functions and pools.

A job function takes one picklable job and returns a picklable value; it knows nothing of the
pool. An `Executor` maps it over jobs and streams `JobResult`s back as they finish, in any order.
A job that raises, or whose process dies, comes back as a failed result while the others go on.

`LocalExecutor` runs every job in a fresh spawned process (libsumo allows one simulation per
process, and a fresh process leaves nothing behind from the previous job), at most `workers` at a
time. A cluster executor (Ray) plugs in behind the same `map_unordered`.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import traceback
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection, wait
from typing import Any, Protocol, runtime_checkable

from simharness.errors import UserError


@dataclasses.dataclass(frozen=True)
class JobResult:
    """What came back for one job: its value, or one line of error text (and the traceback)."""

    job: Any
    value: Any = None
    error: str | None = None
    traceback: str = ""

    @property
    def ok(self) -> bool:
        return self.error is None


@runtime_checkable
class Executor(Protocol):
    """Maps a job function over jobs; results stream back in completion order."""

    workers: int

    def map_unordered(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[JobResult]: ...


def _child(fn: Callable[[Any], Any], job: Any, conn: Connection) -> None:
    """Body of a worker process: run one job, send ("ok", value) or ("error", line, traceback)."""
    try:
        value = fn(job)
    except BaseException as e:  # noqa: B036 - a job's KeyboardInterrupt is reported too
        message = f"{type(e).__name__}: {e}".strip().splitlines()[0]
        conn.send(("error", message, traceback.format_exc()))
    else:
        conn.send(("ok", value))
    finally:
        conn.close()


class LocalExecutor:
    """A spawn-context process per job, at most `workers` at once, on this machine."""

    def __init__(self, workers: int = 2) -> None:
        if workers < 1:
            raise UserError(f"--workers: expected a positive number of processes, got {workers}")
        self.workers = int(workers)
        self._ctx = mp.get_context("spawn")

    def map_unordered(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[JobResult]:
        pending = list(jobs)[::-1]  # pop() from the end keeps the given order
        running: dict[Connection, tuple[Any, Any]] = {}  # reader -> (job, process)
        try:
            while pending or running:
                while pending and len(running) < self.workers:
                    job = pending.pop()
                    reader, writer = self._ctx.Pipe(duplex=False)
                    proc = self._ctx.Process(target=_child, args=(fn, job, writer), daemon=True)
                    proc.start()
                    writer.close()  # the child holds the only writer: EOF here means it died
                    running[reader] = (job, proc)
                for reader in wait(list(running)):
                    job, proc = running.pop(reader)
                    yield self._collect(job, proc, reader)
        finally:
            for reader, (_, proc) in running.items():  # interrupted: stop what still runs
                proc.terminate()
                proc.join(5)
                reader.close()

    @staticmethod
    def _collect(job: Any, proc: Any, reader: Connection) -> JobResult:
        try:
            msg = reader.recv()
        except (EOFError, OSError):
            msg = None
        finally:
            reader.close()
        proc.join()
        if msg is None:
            return JobResult(job, error=f"worker process died (exit code {proc.exitcode})")
        if msg[0] == "ok":
            return JobResult(job, value=msg[1])
        return JobResult(job, error=msg[1], traceback=msg[2])


def make_executor(name: str = "local", workers: int = 2, address: str | None = None) -> Executor:
    """The executor named on the command line ('local'; 'ray' arrives with the cluster issue)."""
    if name == "local":
        if address:
            raise UserError("--address: only used with --executor ray")
        return LocalExecutor(workers)
    if name == "ray":
        raise UserError("--executor ray: not available yet in this version; use --executor local")
    raise UserError(f"--executor: unknown executor {name!r}; expected local or ray")
