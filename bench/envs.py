"""Gym env speed against its backend, measured in one run.

For each env (HighwayDense-v0, SumoDense-v0, default config): env-steps per second of one env driven
by a seeded random policy (rendering off, one core, resets included in the time, as a training loop
sees them), and the raw frames per second of the same backend and scenario in this process stepped
directly (`Simulator.step` with a constant ego command: no observation, reward or worker process), so
the share `raw time / env time` says what the env layer costs. Rates are per CPU-second (this process
plus the env's SUMO worker: a shared machine's load does not count; wall-clock rates are in the JSON),
and the loops run interleaved in chunks so the rest of a busy machine affects them alike. Also the env
with ``episodes_per_warmup = 1`` (every reset warms the traffic up from empty), and
the env loop's share of CPU spent in reset() with the step-only rate and share (resets left out), and what
the env layer proper costs on top of its own simulator: step() CPU beyond the simulator's step() inside it
(observation, reward, ego safety, gym wrappers; the simulator under a random, weaving ego works harder than
in the raw loop's cruise, which this leaves out).

With --reward-table: the default reward's return under three fixed policies (full braking, full throttle,
holding speed), 10 episodes each per env (reset(seed=s) for s in 0..9): mean return, collisions, steps.

Usage: python bench/envs.py [--steps 1000] [--iterations 5] [--env ID] [--against DIR] [--reward-table]
  --against DIR  also compare with the checkout at DIR (e.g. `git archive REV | tar -x -C DIR`): one worker
                 process per checkout (DIR's simharness, default config, this file's loop) runs the same random
                 policy, the two taking turns chunk by chunk; the table gives both env-steps/s, their ratio and
                 each one's CPU per step() split into the simulator's step() and the rest.
Each loop runs 20 untimed steps first (a fresh checkout compiles its numba kernels on the first calls).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
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


def measure(steps: int, iterations: int, env_ids: tuple[str, ...] = ENVS, variants: bool = True) -> dict:
    """Env and raw loops interleaved in `iterations` chunks (a loaded machine slows both alike); rates over all."""
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
        chunk = max(1, steps // iterations)
        for _ in range(iterations):
            for k, loop in (("raw", raw), *loops.items()):
                w, c = loop.run(chunk)
                wall[k] += w
                cpu[k] += c
        n = chunk * iterations
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


def serve(env_id: str) -> None:
    """Worker of `compare`: one `EnvLoop` of the simharness on PYTHONPATH; each line n read from stdin runs n steps
    and is answered with one line [CPU s, of which in reset(), of which in the simulator's step() within step()]."""
    import simharness

    loop = EnvLoop(env_id, {})
    loop.run(20)  # untimed: compiled kernels
    print(json.dumps(str(Path(simharness.__file__).resolve().parents[1])), flush=True)
    for line in sys.stdin:
        loop.reset_cpu, loop.sim_cpu = 0.0, 0.0
        cpu = loop.run(int(line))[1]
        print(json.dumps([cpu, loop.reset_cpu, loop.sim_cpu]), flush=True)
    loop.env.close()


def compare(other: Path, steps: int, iterations: int, env_ids: tuple[str, ...] = ENVS) -> dict[str, dict]:
    """Env-steps per CPU-second of this checkout's env and of the checkout at `other`, each in a worker process
    (`serve`), the two stepping in turn in `iterations` chunks; their ratio (this / other); and each one's CPU per
    step() (resets left out) split into the simulator's step() and the rest (the env layer), in microseconds."""
    here = Path(__file__).resolve().parents[1]
    out = {}
    for env_id in env_ids:
        workers = {}
        for name, root in (("this", here), ("other", other.resolve())):
            proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--serve", env_id], cwd=root,
                                    env={**os.environ, "PYTHONPATH": str(root)}, stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, text=True)
            workers[name] = proc
            found = json.loads(proc.stdout.readline() or "null")
            if found != str(root):  # the worker must run that checkout's simharness, not an installed one
                for w in workers.values():
                    w.kill()
                    w.wait()
                raise SystemExit(f"--against: the worker for {root} failed or imported simharness from {found}")
        cpu = {name: [0.0, 0.0, 0.0] for name in workers}  # CPU s: all, in reset(), in the simulator within step()
        chunk = max(1, steps // iterations)
        for _ in range(iterations):
            for name, proc in workers.items():
                proc.stdin.write(f"{chunk}\n")
                proc.stdin.flush()
                cpu[name] = [a + b for a, b in zip(cpu[name], json.loads(proc.stdout.readline()), strict=True)]
        for proc in workers.values():
            proc.stdin.close()
            proc.wait()
        n = chunk * iterations
        rec = {"ratio": cpu["other"][0] / cpu["this"][0]}
        for name, (total, reset, sim) in cpu.items():
            rec[f"{name}_steps_per_s"] = n / total
            rec[f"{name}_sim_us_per_step"] = 1e6 * sim / n
            rec[f"{name}_layer_us_per_step"] = 1e6 * (total - reset - sim) / n
        out[env_id] = rec
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=1000, help="env steps (and raw frames) per loop")
    p.add_argument("--iterations", type=int, default=5, help="interleaved chunks")
    p.add_argument("--against", type=Path, default=None, help="another checkout's directory to compare with")
    p.add_argument("--env", choices=ENVS, default=None, help="one env only")
    p.add_argument("--reward-table", action="store_true", help="fixed policies' returns instead of speeds")
    p.add_argument("--episodes", type=int, default=10, help="episodes per policy for --reward-table")
    p.add_argument("--serve", choices=ENVS, default=None, help=argparse.SUPPRESS)  # a `compare` worker
    a = p.parse_args()
    if a.serve:
        serve(a.serve)
        return
    ids = (a.env,) if a.env else ENVS
    if a.reward_table:
        table = reward_table(a.episodes, ids)
        print_reward_table(table)
        print(json.dumps(table))
        return
    res = measure(a.steps, a.iterations, ids)
    print(f"{'env':16s} {'raw fr/s':>9s} {'env st/s':>9s} {'share':>6s} {'in reset':>8s} {'step-only st/s':>15s} "
          f"{'share':>6s} {'layer on sim':>12s} {'cold-reset st/s':>16s} {'share':>6s}")
    for k, r in res.items():
        print(f"{k:16s} {r['raw_frames_per_s']:9.0f} {r['env_steps_per_s']:9.0f} {r['env_share_of_raw']:6.0%} "
              f"{r['env_reset_cpu_share']:8.0%} {r['env_step_only_per_s']:15.0f} "
              f"{r['env_step_only_share_of_raw']:6.0%} {r['env_layer_on_top_of_sim']:12.0%} "
              f"{r['env_cold_resets_steps_per_s']:16.0f} {r['env_cold_resets_share_of_raw']:6.0%}")
    against = compare(a.against, a.steps, a.iterations, ids) if a.against else {}
    if against:
        print(f"\nagainst {a.against}: env-steps per CPU-second in turn in worker processes, ratio this / other, "
              "and CPU per step() (resets left out): the simulator's step() and the rest (env layer, action sampling)")
        print(f"{'env':16s} {'this':>7s} {'other':>7s} {'ratio':>6s} {'this: sim us':>12s} {'layer us':>8s} "
              f"{'other: sim us':>13s} {'layer us':>8s}")
        for k, r in against.items():
            print(f"{k:16s} {r['this_steps_per_s']:7.0f} {r['other_steps_per_s']:7.0f} {r['ratio']:6.2f} "
                  f"{r['this_sim_us_per_step']:12.0f} {r['this_layer_us_per_step']:8.0f} "
                  f"{r['other_sim_us_per_step']:13.0f} {r['other_layer_us_per_step']:8.0f}")
    print(json.dumps({"now": res, "against": against, "steps": a.steps, "iterations": a.iterations}))


if __name__ == "__main__":
    main()
