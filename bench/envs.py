"""Gym env speed against its backend, measured in one run.

For each env (HighwayDense-v0, SumoDense-v0, default config): env-steps per second of one env driven
by a seeded random policy (rendering off, one core, resets included in the time, as a training loop
sees them), and the raw frames per second of the same backend and scenario in this process stepped
directly (`Simulator.step` with a constant ego command: no observation, reward or worker process), so
the share `raw time / env time` says what the env layer costs. Rates are per CPU-second (this process
plus the env's SUMO worker: a shared machine's load does not count; wall-clock rates are in the JSON),
and the loops run interleaved in chunks so the rest of a busy machine affects them alike. Also the env
with ``episodes_per_warmup = 1`` (every reset warms the traffic up from empty, as before warm resets), and
the env loop's share of CPU spent in reset() with the step-only rate and share (resets left out), and what
the env layer proper costs on top of its own simulator: step() CPU beyond the simulator's step() inside it
(observation, reward, ego safety, gym wrappers; the simulator under a random, weaving ego works harder than
in the raw loop's cruise, which this leaves out).

With --reward-table: the default reward's return under three fixed policies (full braking, full throttle,
holding speed), 10 episodes each per env (reset(seed=s) for s in 0..9): mean return, collisions, steps.

Usage: python bench/envs.py [--steps 1000] [--rounds 5] [--env ID] [--old REV] [--reward-table]
  --old REV  also measure the env of git revision REV (checked out into a temporary worktree, run in a
             subprocess after this run's loops): its env-steps/s and env layer, for a before/after table.
Each loop runs 20 untimed steps first (a fresh checkout compiles its numba kernels on the first calls).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")


ENVS = ("HighwayDense-v0", "SumoDense-v0")


class EnvLoop:
    """One env under a seeded random policy; `run(n)` steps it n times (resets included) and returns seconds."""

    def __init__(self, env_id: str, config: dict, seed: int = 0) -> None:
        import gymnasium as gym

        import simharness.envs  # noqa: F401 - registers the ids

        self.env = gym.make(f"simharness/{env_id}", config=config)
        self.env.action_space.seed(seed)
        self.env.reset(seed=seed)
        self.resets = 0
        self.reset_cpu = 0.0  # CPU seconds spent in reset() (warm-ups, the ego's history), within run()
        self.sim_cpu = 0.0  # CPU seconds spent in the simulator's step() within the env's step(), within run()
        self._in_step = False
        sim = self.env.unwrapped._sim
        sim_step = sim.step

        def timed_step(*args: object, **kwargs: object) -> object:
            if not self._in_step:
                return sim_step(*args, **kwargs)
            c = cpu_seconds(self.env)
            try:
                return sim_step(*args, **kwargs)
            finally:
                self.sim_cpu += cpu_seconds(self.env) - c

        sim.step = timed_step

    def run(self, n: int) -> tuple[float, float]:
        w0, c0 = time.perf_counter(), cpu_seconds(self.env)
        for _ in range(n):
            action = self.env.action_space.sample()
            self._in_step = True
            try:
                _, _, term, trunc, _ = self.env.step(action)
            finally:
                self._in_step = False
            if term or trunc:
                r0 = cpu_seconds(self.env)
                self.env.reset()
                self.reset_cpu += cpu_seconds(self.env) - r0
                self.resets += 1
        return time.perf_counter() - w0, cpu_seconds(self.env) - c0


class RawLoop:
    """The env's own backend and scenario in this process, stepped directly with a constant ego command."""

    def __init__(self, env_id: str, seed: int = 0) -> None:
        import gymnasium as gym

        import simharness.envs  # noqa: F401
        from simharness.sim import EgoCommand, make_simulator

        env = gym.make(f"simharness/{env_id}")
        spec = env.unwrapped.spec_.with_overrides({"duration": 3600.0})
        env.close()
        self.sim = make_simulator(spec)
        self.sim.reset(seed)
        self.command = EgoCommand(0.0, 0.0)

    def run(self, n: int) -> tuple[float, float]:
        w0, c0 = time.perf_counter(), time.process_time()
        for _ in range(n):
            self.sim.step(self.command)
        return time.perf_counter() - w0, time.process_time() - c0


def cpu_seconds(env: object = None) -> float:
    """CPU seconds of this process plus, for an env whose simulator runs in a worker, that worker's."""
    total = time.process_time()
    pid = getattr(getattr(getattr(env, "unwrapped", None), "_sim", None), "_pid", None)
    if pid:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime
    return total


def measure(steps: int, rounds: int, env_ids: tuple[str, ...] = ENVS, variants: bool = True) -> dict:
    """Env and raw loops interleaved in `rounds` chunks (a loaded machine slows both alike); rates over all."""
    out = {}
    for env_id in env_ids:
        loops = {"env": EnvLoop(env_id, {})}
        if variants:  # every reset warms the traffic up afresh (the behaviour before warm resets)
            loops["env_cold_resets"] = EnvLoop(env_id, {"episodes_per_warmup": 1})
        raw = RawLoop(env_id)
        for loop in (raw, *loops.values()):  # warm up: compiled kernels (a fresh checkout's first calls) untimed
            loop.run(20)
        for loop in loops.values():
            loop.resets, loop.reset_cpu, loop.sim_cpu = 0, 0.0, 0.0
        wall = dict.fromkeys([*loops, "raw"], 0.0)
        cpu = dict(wall)
        chunk = max(1, steps // rounds)
        for _ in range(rounds):
            for k, loop in (("raw", raw), *loops.items()):
                w, c = loop.run(chunk)
                wall[k] += w
                cpu[k] += c
        n = chunk * rounds
        rec = {"raw_frames_per_s": n / cpu["raw"], "raw_frames_per_wall_s": n / wall["raw"]}
        for k in loops:
            rec[f"{k}_steps_per_s"] = n / cpu[k]
            rec[f"{k}_steps_per_wall_s"] = n / wall[k]
            rec[f"{k}_share_of_raw"] = cpu["raw"] / cpu[k]
            rec[f"{k}_resets"] = loops[k].resets
            rec[f"{k}_reset_cpu_share"] = loops[k].reset_cpu / cpu[k]
            # step() alone (resets left out): what the env layer costs on top of the simulator per step
            rec[f"{k}_step_only_per_s"] = n / (cpu[k] - loops[k].reset_cpu)
            rec[f"{k}_step_only_share_of_raw"] = cpu["raw"] / (cpu[k] - loops[k].reset_cpu)
            # the env layer proper: step() time beyond its own simulator steps (observation, reward, safety, ...)
            rec[f"{k}_layer_on_top_of_sim"] = (cpu[k] - loops[k].reset_cpu) / loops[k].sim_cpu - 1.0
        out[env_id] = rec
        raw.sim.close()
        for loop in loops.values():
            loop.env.close()
    return out


FIXED_POLICIES = {"brake": (-1.0, 0.0), "throttle": (1.0, 0.0), "hold": (0.0, 0.0)}  # continuous actions


def reward_table(episodes: int = 10, env_ids: tuple[str, ...] = ENVS) -> dict[str, dict[str, dict[str, float]]]:
    """Return, collision share, steps and progress (m) of each fixed policy over `episodes` seeded episodes
    (seeds 0..episodes-1, the same for every policy) of each env at its default config."""
    import gymnasium as gym
    import numpy as np

    import simharness.envs  # noqa: F401

    out: dict[str, dict[str, dict[str, float]]] = {}
    for env_id in env_ids:
        env = gym.make(f"simharness/{env_id}")
        out[env_id] = {}
        for name, action in FIXED_POLICIES.items():
            act = np.asarray(action, np.float32)
            returns, collided, steps, progress = [], [], [], []
            for seed in range(episodes):
                env.reset(seed=seed)
                total, n, done, info = 0.0, 0, False, {}
                while not done:
                    _, r, term, trunc, info = env.step(act)
                    total, n, done = total + r, n + 1, term or trunc
                returns.append(total)
                collided.append(float(info["collided"]))
                steps.append(n)
                progress.append(info["progress_m"])
            out[env_id][name] = {"return": float(np.mean(returns)), "return_min": float(np.min(returns)),
                                 "return_max": float(np.max(returns)), "collided": float(np.mean(collided)),
                                 "steps": float(np.mean(steps)), "progress_m": float(np.mean(progress))}
        env.close()
    return out


def print_reward_table(table: dict[str, dict[str, dict[str, float]]]) -> None:
    print(f"{'env':16s} {'policy':9s} {'return':>8s} {'[min, max]':>18s} {'collided':>8s} {'steps':>6s} "
          f"{'progress m':>10s}")
    for env_id, rows in table.items():
        for name, r in rows.items():
            print(f"{env_id:16s} {name:9s} {r['return']:8.1f} [{r['return_min']:7.1f}, {r['return_max']:7.1f}] "
                  f"{r['collided']:8.0%} {r['steps']:6.1f} {r['progress_m']:10.1f}")


def measure_old(rev: str, steps: int, rounds: int, env_ids: tuple[str, ...] = ENVS) -> dict[str, dict]:
    """`measure` (without variants) of revision `rev` (its own simharness, default config) in a subprocess."""
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="simharness_old_") as tmp:
        wt = Path(tmp) / "wt"
        subprocess.run(["git", "-C", str(root), "worktree", "add", "--detach", str(wt), rev], check=True,
                       capture_output=True)
        try:
            code = ("import json, sys; sys.path.insert(0, sys.argv[1]); from envs_bench import measure; "
                    f"print(json.dumps(measure({steps}, {rounds}, {tuple(env_ids)!r}, variants=False)))")
            (Path(tmp) / "envs_bench.py").write_text(Path(__file__).read_text())
            env = {**os.environ, "PYTHONPATH": str(wt)}
            proc = subprocess.run([sys.executable, "-c", code, tmp], capture_output=True, text=True, env=env,
                                  cwd=wt, check=True)
            return json.loads(proc.stdout.strip().splitlines()[-1])
        finally:
            subprocess.run(["git", "-C", str(root), "worktree", "remove", "--force", str(wt)], capture_output=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=1000, help="env steps (and raw frames) per loop")
    p.add_argument("--rounds", type=int, default=5, help="interleaved chunks")
    p.add_argument("--old", default=None, help="git revision to compare with")
    p.add_argument("--env", choices=ENVS, default=None, help="one env only")
    p.add_argument("--reward-table", action="store_true", help="fixed policies' returns instead of speeds")
    p.add_argument("--episodes", type=int, default=10, help="episodes per policy for --reward-table")
    a = p.parse_args()
    ids = (a.env,) if a.env else ENVS
    if a.reward_table:
        table = reward_table(a.episodes, ids)
        print_reward_table(table)
        print(json.dumps(table))
        return
    res = measure(a.steps, a.rounds, ids)
    old = measure_old(a.old, a.steps, a.rounds, ids) if a.old else {}
    print(f"{'env':16s} {'raw fr/s':>9s} {'env st/s':>9s} {'share':>6s} {'in reset':>8s} {'step-only st/s':>15s} "
          f"{'share':>6s} {'layer on sim':>12s} {'cold-reset st/s':>16s} {'share':>6s}"
          + (f" {'old st/s':>9s} {'old layer':>9s}" if old else ""))
    for k, r in res.items():
        line = (f"{k:16s} {r['raw_frames_per_s']:9.0f} {r['env_steps_per_s']:9.0f} {r['env_share_of_raw']:6.0%} "
                f"{r['env_reset_cpu_share']:8.0%} {r['env_step_only_per_s']:15.0f} "
                f"{r['env_step_only_share_of_raw']:6.0%} {r['env_layer_on_top_of_sim']:12.0%} "
                f"{r['env_cold_resets_steps_per_s']:16.0f} {r['env_cold_resets_share_of_raw']:6.0%}")
        if k in old:
            line += f" {old[k]['env_steps_per_s']:9.0f} {old[k]['env_layer_on_top_of_sim']:9.0%}"
        print(line)
    print(json.dumps({"now": res, "old": old, "steps": a.steps, "rounds": a.rounds}))


if __name__ == "__main__":
    main()
