"""`SumoProcess`: a libsumo simulation in its own worker process, so one process can hold any number.

libsumo keeps one simulation per process (`SumoSimulator` refuses a second). A `SumoProcess` runs a
`SumoSimulator` in a worker (a fresh Python started with `subprocess`, so it also works inside
daemonic processes such as SB3's `SubprocVecEnv` or gymnasium's `AsyncVectorEnv` workers) and talks
to it over a socket pair with small pickled messages; frames come back as `Frame`s of numpy arrays.
It follows the same `Simulator` protocol, and a given seed gives the same frames as an in-process
`SumoSimulator` (tests/test_sumo_process.py).

API (all methods block until the worker answers):

- ``SumoProcess(spec)``: start the worker and build the network; ``.spec``, ``.dt``, ``.road`` as
  on `SumoSimulator`.
- ``reset(seed) -> Frame``, ``step(ego_command=None) -> Frame``, ``advance_unrecorded(frames)``,
  ``restart_ego() -> Frame``: exactly `SumoSimulator`'s.
- ``branch() -> SumoProcess``: an independent copy of the running simulation, made by ``os.fork()``
  of the worker (libsumo's whole state, SUMO's RNGs and the harness bookkeeping are copied by the
  fork). Stepping the branch never touches the original; the branch stepped with the same ego
  commands gives the same frames as the original would. A branch can branch again; ``reset`` on a
  branch starts a fresh simulation in it.
- ``rollout(drive, frame, start, stop, snapshots) -> (frames, commands, branches)``: frames start + 1 .. stop
  with the ego's command at each frame i given by ``drive(i, frame_i)``, a picklable callable run in the
  worker: one message for the whole stretch instead of one round trip per frame (what a closed-loop ego
  needs, when its planner can run where the simulation is: the exact oracle's branches). ``branches``
  holds a ``branch()`` taken at each index in ``snapshots`` (before stepping there). The same frames as
  stepping with those commands from here.
- ``close()``: end the simulation and the worker (also done on garbage collection and at exit).
- ``alive``: whether the worker is still there.

A worker that dies (SUMO crash, killed) makes the next call raise `SimulatorError` with one line naming
the scenario; errors inside the worker come back as the same `SimulatorError` / `UserError` /
`ValueError` text. `make_simulator(spec, process=True)` returns a `SumoProcess` for sumo scenarios.
"""

from __future__ import annotations

import os
import pickle
import shutil
import signal
import socket
import subprocess
import sys
import weakref
from collections.abc import Callable, Sequence
from multiprocessing import reduction
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from simharness.errors import SimulatorError, UserError
from simharness.scenario import ScenarioSpec
from simharness.sim.base import EgoCommand, Frame, RoadGeometry

_ERRORS: dict[str, type[Exception]] = {"SimulatorError": SimulatorError, "UserError": UserError,
                                       "ValueError": ValueError}
_START_TIMEOUT = 120.0  # s for the worker to import libsumo and build the network


class SumoProcess:
    """`Simulator` over a `SumoSimulator` in a worker process; see the module doc."""

    def __init__(self, spec: ScenarioSpec, *, _conn: Connection | None = None, _pid: int | None = None,
                 _road: RoadGeometry | None = None) -> None:
        if spec.backend != "sumo":
            raise ValueError(f"SumoProcess needs a sumo scenario, got backend {spec.backend!r}")
        self.spec = spec
        self.dt = spec.dt
        self.seed: int | None = None
        popen = None
        if _conn is None:  # a new worker; branches arrive with their connection made
            ours, theirs = socket.socketpair()
            root = str(Path(__file__).resolve().parents[2])
            env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]).rstrip(
                os.pathsep), "LIBSUMO_AS_TRACI": "quiet", "OMP_NUM_THREADS": "1"}
            popen = subprocess.Popen([sys.executable, "-m", "simharness.sim.sumo.process", str(theirs.fileno())],
                                     pass_fds=(theirs.fileno(),), env=env, stdin=subprocess.DEVNULL)
            theirs.close()
            _conn, _pid = Connection(ours.detach()), popen.pid
            _conn.send(pickle.dumps(spec))
        self._conn: Connection | None = _conn
        self._pid = int(_pid) if _pid is not None else -1
        self._popen = popen
        self._finalizer = weakref.finalize(self, _shutdown, _conn, popen, self._pid)
        if _road is None:
            if not _conn.poll(_START_TIMEOUT):
                self.close()
                raise SimulatorError(f"scenario {spec.name}: the SUMO worker did not start within "
                                     f"{_START_TIMEOUT:g} s")
            try:
                _road = self._answer("start")
            except BaseException:
                self.close()
                raise
        self.road: RoadGeometry = _road

    # ------------------------------------------------------------------ Simulator protocol
    def reset(self, seed: int) -> Frame:
        """Start SUMO with seed `spec.seed + seed` in the worker; the frame at t = 0."""
        frame = self._call("reset", int(seed))
        self.seed = int(seed)
        return frame

    def step(self, ego_command: EgoCommand | None = None) -> Frame:
        """Advance one recorded frame; the ego follows `ego_command` (None: SUMO's own models)."""
        return self._call("step", ego_command)

    def restart_ego(self) -> Frame:
        """`SumoSimulator.restart_ego` in the worker: a new ego run in the running traffic."""
        return self._call("restart_ego", None)

    def advance_unrecorded(self, frames: int) -> None:
        """`SumoSimulator.advance_unrecorded` in the worker."""
        self._call("advance_unrecorded", int(frames))

    def branch(self) -> SumoProcess:
        """An independent copy of the running simulation (the worker forks); see the module doc."""
        conn = self._require()
        ours, theirs = socket.socketpair()
        try:
            conn.send(("branch", None))
            reduction.send_handle(conn, theirs.fileno(), self._pid)
        except OSError:
            ours.close()
            theirs.close()
            raise self._died() from None
        finally:
            theirs.close()
        pid = self._answer("branch")
        child = SumoProcess(self.spec, _conn=Connection(ours.detach()), _pid=pid, _road=self.road)
        child.seed = self.seed
        return child

    def rollout(self, drive: Callable[[int, Frame], EgoCommand | None], frame: Frame, start: int, stop: int,
                snapshots: Sequence[int] = ()) -> tuple[list[Frame], list[EgoCommand | None], dict[int, SumoProcess]]:
        """Step from frame index `start` (this simulation is there now; `frame` is that frame) to `stop`, the ego's
        command at each frame i being `drive(i, frame_i)`, run in the worker (see the module doc).

        -> frames start + 1 .. stop, the commands at start .. stop - 1, and {i: branch at frame i} for i in
        `snapshots` (indices in [start, stop)). The worker imports `drive`'s module when it first unpickles one:
        an empty rollout (start == stop) on a simulation before branching it does that once for every branch.
        """
        conn = self._require()
        at = sorted(set(snapshots))
        pairs = [socket.socketpair() for _ in at]
        try:
            conn.send(("rollout", (drive, frame, int(start), int(stop), at)))
            for _, theirs in pairs:
                reduction.send_handle(conn, theirs.fileno(), self._pid)
        except OSError:
            for ours, _ in pairs:
                ours.close()
            raise self._died() from None
        finally:
            for _, theirs in pairs:
                theirs.close()
        try:
            frames, commands, pids = self._answer("rollout")
        except BaseException:
            for ours, _ in pairs:
                ours.close()
            raise
        branches = {}
        for i, (ours, _), pid in zip(at, pairs, pids, strict=True):
            branches[i] = SumoProcess(self.spec, _conn=Connection(ours.detach()), _pid=pid, _road=self.road)
            branches[i].seed = self.seed
        return frames, commands, branches

    @property
    def alive(self) -> bool:
        return self._conn is not None and not self._conn.closed and _pid_alive(self._pid)

    def close(self) -> None:
        """End the simulation and its worker; idempotent."""
        self._finalizer()
        self._conn = None

    def __enter__(self) -> SumoProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ messaging
    def _require(self) -> Connection:
        if self._conn is None:
            raise SimulatorError(f"scenario {self.spec.name}: SumoProcess is closed")
        return self._conn

    def _call(self, op: str, arg: Any) -> Any:
        conn = self._require()
        try:
            conn.send((op, arg))
        except OSError:
            raise self._died() from None
        return self._answer(op)

    def _answer(self, op: str) -> Any:
        conn = self._require()
        try:
            status, value = conn.recv()
        except (EOFError, OSError):
            raise self._died() from None
        if status == "ok":
            return value
        kind, message = value
        if kind not in _ERRORS:  # libsumo's own exceptions: say where
            message = f"scenario {self.spec.name}, seed {self.seed}: SUMO worker {op}: {kind}: {message}"
        raise _ERRORS.get(kind, SimulatorError)(message)

    def _died(self) -> SimulatorError:
        code = None
        if self._popen is not None:
            try:
                code = self._popen.wait(timeout=2)
            except subprocess.TimeoutExpired:
                pass
        self.close()
        how = f" (exit status {code})" if code is not None else ""
        return SimulatorError(f"scenario {self.spec.name}, seed {self.seed}: the SUMO worker process "
                              f"{self._pid} died{how}")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except (OSError, ValueError):
        return False
    return True


def _shutdown(conn: Connection, popen: subprocess.Popen | None, pid: int) -> None:
    """Ask the worker to stop, then make sure it has (finalizer: runs on close, GC and at exit)."""
    try:
        conn.send(("close", None))
    except Exception:  # already gone
        pass
    try:
        conn.close()
    except Exception:
        pass
    if popen is not None:
        try:
            popen.wait(timeout=10)
        except subprocess.TimeoutExpired:
            popen.kill()
            popen.wait()


# ---------------------------------------------------------------------- worker side
def _serve(conn: Connection, sim: Any, spec: ScenarioSpec, forked: bool) -> None:
    """Answer requests until "close" or the other end goes away."""
    while True:
        try:
            op, arg = conn.recv()
        except (EOFError, OSError):
            break
        if op == "close":
            break
        try:
            if op == "branch":
                fd = reduction.recv_handle(conn)
                pid = os.fork()
                if pid == 0:  # the copy: serve the new connection only
                    conn.close()
                    _serve(Connection(fd), sim, spec, forked=True)
                    return
                os.close(fd)
                value: Any = pid
            elif op == "reset":
                if forked:  # a forked copy shares the original's files: a fresh simulator owns its own
                    sim.close()
                    from simharness.sim.sumo.simulator import SumoSimulator

                    sim, forked = SumoSimulator(spec), False
                value = sim.reset(arg)
            elif op == "step":
                value = sim.step(arg)
            elif op == "rollout":
                value = _rollout(conn, sim, spec, *arg)
                if value is None:  # a snapshot's copy: it has served its own connection and is done
                    return
            elif op == "restart_ego":
                value = sim.restart_ego()
            elif op == "advance_unrecorded":
                value = sim.advance_unrecorded(arg)
            else:
                raise ValueError(f"SumoProcess worker: unknown request {op!r}")
            conn.send(("ok", value))
        except Exception as e:  # report, keep serving: the caller decides
            conn.send(("err", (type(e).__name__, str(e) or type(e).__name__)))
    if not forked:
        sim.close()
        shutil.rmtree(sim._folder, ignore_errors=True)  # os._exit below skips SumoSimulator.__del__


def _rollout(conn: Connection, sim: Any, spec: ScenarioSpec, drive: Callable[[int, Frame], EgoCommand | None],
             frame: Frame, start: int, stop: int, at: list[int]) -> tuple | None:
    """The worker's side of `SumoProcess.rollout`: (frames, commands, snapshot pids), or None in a snapshot's copy
    once its connection has closed."""
    fds = {i: reduction.recv_handle(conn) for i in at}
    frames, commands, pids = [], [], []
    try:
        for i in range(start, stop):
            if i in fds:  # a snapshot: the copy serves its own connection, as after "branch"
                fd = fds.pop(i)
                pid = os.fork()
                if pid == 0:
                    conn.close()
                    for other in fds.values():
                        os.close(other)
                    fds.clear()
                    _serve(Connection(fd), sim, spec, forked=True)
                    return None
                os.close(fd)
                pids.append(pid)
            commands.append(drive(i, frame))
            frame = sim.step(commands[-1])
            frames.append(frame)
    finally:
        for fd in fds.values():
            os.close(fd)
    return frames, commands, pids


def _worker_main(fd: int) -> None:
    conn = Connection(fd)
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # forked branches are reaped by the kernel
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the caller, which closes us
    spec = pickle.loads(conn.recv())
    try:
        from simharness.sim.sumo.simulator import SumoSimulator

        sim = SumoSimulator(spec)
    except Exception as e:
        conn.send(("err", (type(e).__name__, str(e) or type(e).__name__)))
        return
    conn.send(("ok", sim.road))
    _serve(conn, sim, spec, forked=False)


if __name__ == "__main__":
    _worker_main(int(sys.argv[1]))
    os._exit(0)  # forked copies and the worker end here, without running libsumo's or Python's exit hooks twice
