"""SumoProcess on real libsumo: several per process, same frames as in-process, branches, worker death, cleanup."""

from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from simharness.errors import SimulatorError
from simharness.scenario import load_scenario
from simharness.sim import make_simulator
from simharness.sim.base import EgoCommand, Frame
from simharness.sim.sumo.process import SumoProcess
from simharness.sim.sumo.simulator import SumoSimulator

SPEC = load_scenario("sumo_arterial_dense").with_overrides(
    {"warmup": 20.0, "duration": 30.0, "ego.enabled": True, "ego.insert_at": 0.0})


def _command(k: int) -> EgoCommand | None:
    """SUMO drives the ego for 3 frames (it enters), then the harness does, with some steering."""
    return None if k < 3 else EgoCommand(1.5 * np.sin(k / 3.0), 0.4 * np.cos(k / 2.0))


def _same(a: Frame, b: Frame) -> bool:
    arrays = ("agent_id", "agent_type", "xy", "heading", "speed", "length", "width")
    return (a.t == b.t and a.ego == b.ego and a.events == b.events and set(a.extra) == set(b.extra)
            and all(np.array_equal(getattr(a, f), getattr(b, f)) for f in arrays)
            and all(np.array_equal(a.extra[k], b.extra[k]) for k in a.extra))


def _run(sim, seed: int, n: int, start: int = 0) -> list[Frame]:
    frames = [sim.reset(seed)] if start == 0 else []
    frames += [sim.step(_command(k)) for k in range(start, start + n)]
    return frames


def test_two_processes_match_a_lone_in_process_simulator():
    first, second = SumoProcess(SPEC), make_simulator(SPEC, process=True)
    assert isinstance(second, SumoProcess) and second.dt == SPEC.dt
    try:
        a, b = _run(first, 3, 12), _run(second, 3, 12)
        other = second.reset(4)
    finally:
        first.close()
        second.close()
    lone = SumoSimulator(SPEC)
    try:
        ref = _run(lone, 3, 12)
    finally:
        lone.close()
    assert ref[-1].ego >= 0 and ref[-1].num_agents > 10
    assert all(_same(x, y) for x, y in zip(a, ref, strict=True))
    assert all(_same(x, y) for x, y in zip(b, ref, strict=True))
    assert not _same(other, ref[0])
    assert first.road.bounds() == lone.road.bounds()


def test_branch_leaves_the_original_alone_and_matches_it():
    sim = SumoProcess(SPEC)
    try:
        _run(sim, 5, 6)
        branch = sim.branch()
        ahead = [branch.step(_command(k)) for k in range(6, 14)]
        assert branch.seed == 5 and branch.alive
        # The original has not moved: its next frames are what the branch saw, step for step.
        same = [sim.step(_command(k)) for k in range(6, 14)]
        assert all(_same(x, y) for x, y in zip(ahead, same, strict=True))
        assert ahead[0].t == pytest.approx(7 * SPEC.dt)
        # A branch of a branch, stepped differently, diverges from its parent's later frames.
        twig = branch.branch()
        brake = [twig.step(EgoCommand(-5.0, 0.0)) for _ in range(4)]
        cruise = [branch.step(_command(k)) for k in range(14, 18)]
        ego = [(f.xy[f.ego], g.xy[g.ego]) for f, g in zip(brake, cruise, strict=True)]
        assert np.linalg.norm(ego[-1][0] - ego[-1][1]) > 1.0
        twig.close()
        branch.close()
        assert not branch.alive
        # Closing branches never touches the original.
        assert sim.step(None).t == pytest.approx(15 * SPEC.dt)
        again = sim.branch()
        assert again.reset(5).t == 0.0  # a branch can start afresh too
        again.close()
    finally:
        sim.close()


def test_rollout_in_the_worker_gives_the_frames_of_stepping_and_snapshots_to_resume_from():
    from simharness.closedloop.oracles import _Drive

    sim = SumoProcess(SPEC)
    try:
        frame = _run(sim, 5, 6)[-1]
        branch = sim.branch()
        commands = [_command(k) for k in range(6, 18)]
        drive = _Drive(SPEC.dt, 25, 60.0, 6, (None, None, None), None, commands)  # replays `commands` only
        frames, issued, snaps = sim.rollout(drive, frame, 0, len(commands), snapshots=[0, 5, 10])
        stepped = [branch.step(c) for c in commands]
        assert issued == commands and sorted(snaps) == [0, 5, 10]
        assert all(_same(x, y) for x, y in zip(frames, stepped, strict=True))
        # A snapshot is the simulation at its frame: stepped on, it gives the rolled-out frames from there.
        again = [snaps[5].step(c) for c in commands[5:]]
        assert all(_same(x, y) for x, y in zip(again, frames[5:], strict=True))
        assert sim.rollout(drive, frames[-1], 12, 12) == ([], [], {})  # an empty stretch: nothing moves
        assert _same(sim.step(None), branch.step(None))
        for s in (*snaps.values(), branch):
            s.close()
    finally:
        sim.close()


def test_worker_death_is_one_clear_error_and_close_reaps():
    sim = SumoProcess(SPEC)
    sim.reset(1)
    os.kill(sim._pid, signal.SIGKILL)
    with pytest.raises(SimulatorError) as err:
        sim.step(None)
    msg = str(err.value)
    assert "\n" not in msg and "sumo_arterial_dense" in msg and "died" in msg
    with pytest.raises(SimulatorError, match="closed"):
        sim.step(None)
    # Bad input inside the worker comes back as the backend's own error, and the worker keeps serving.
    ok = SumoProcess(SPEC)
    pid = ok._pid
    with pytest.raises(SimulatorError, match="not running"):
        ok.step(None)
    assert ok.reset(0).num_agents > 0
    del ok
    gc.collect()
    time.sleep(0.2)
    assert not _alive(pid)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except OSError:
        return False
    # A zombie is dead too.
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split(")")[-1].split()[0] != "Z"


def test_workers_end_with_their_owner():
    script = textwrap.dedent("""
        from simharness.scenario import load_scenario
        from simharness.sim.sumo.process import SumoProcess
        spec = load_scenario("sumo_arterial_dense").with_overrides({"warmup": 5.0})
        sim = SumoProcess(spec)
        sim.reset(0)
        branch = sim.branch()
        print(sim._pid, branch._pid, flush=True)
    """)  # exits without closing either
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    pids = [int(p) for p in proc.stdout.split()]
    deadline = time.time() + 10
    while any(_alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in pids)


def test_restart_ego_in_running_traffic_matches_in_process():
    """The ego leaves and enters again while traffic runs on; the worker and in-process give the same frames."""
    def run(sim) -> list[Frame]:
        frames = _run(sim, 2, 10)
        frames.append(sim.restart_ego())
        frames += [sim.step(_command(k)) for k in range(6)]
        return frames

    proc = SumoProcess(SPEC)
    try:
        a = run(proc)
    finally:
        proc.close()
    lone = SumoSimulator(SPEC)
    try:
        b = run(lone)
    finally:
        lone.close()
    assert all(_same(x, y) for x, y in zip(a, b, strict=True))
    restart = a[11]
    assert restart.t == 0.0 and restart.ego < 0  # out now, back at the next step
    assert a[12].ego >= 0 and a[-1].ego >= 0 and a[-1].t == pytest.approx(6 * SPEC.dt)
    # Traffic ran on: most vehicles of the last frame before the restart are still there.
    assert np.isin(a[10].agent_id, restart.agent_id).mean() > 0.8
