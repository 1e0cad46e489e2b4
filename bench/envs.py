"""Gym env speed against its backend, measured in one run (issue 12).

For each env (HighwayDense-v0, SumoDense-v0): env-steps per second of one env driven by a random policy
(rendering off, one core, resets included in the time, as a training loop sees it), and the raw frames
per second of the same backend and scenario stepped directly (`Simulator.step` with a constant ego
command, no observation or reward), so the share `env / raw` says what the env layer costs.

Usage: python bench/envs.py [--steps 600] [--old REV]
  --old REV  also measure the env of git revision REV (checked out into a temporary worktree, run in a
             subprocess) for a before/after table.
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


ENVS = {"HighwayDense-v0": {"warmup": 10.0}, "SumoDense-v0": {"warmup": 30.0}}


def env_rate(env_id: str, config: dict, steps: int, seed: int = 0) -> float:
    """Env-steps per second of `env_id` under a seeded random policy (resets counted in the time)."""
    import gymnasium as gym

    import simharness.envs  # noqa: F401 - registers the ids

    env = gym.make(f"simharness/{env_id}", config=config)
    env.action_space.seed(seed)
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if term or trunc:
            env.reset()
    rate = steps / (time.perf_counter() - t0)
    env.close()
    return rate


def raw_rate(env_id: str, config: dict, steps: int, seed: int = 0) -> float:
    """Frames per second of the env's own backend and scenario, stepped directly with a constant ego command."""
    import gymnasium as gym

    import simharness.envs  # noqa: F401
    from simharness.sim import EgoCommand, make_simulator

    env = gym.make(f"simharness/{env_id}", config=config)
    spec = env.unwrapped.spec_.with_overrides({"duration": 3600.0})
    env.close()
    sim = make_simulator(spec)
    sim.reset(seed)
    command = EgoCommand(0.0, 0.0)
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step(command)
    rate = steps / (time.perf_counter() - t0)
    sim.close()
    return rate


def measure(steps: int) -> dict[str, dict[str, float]]:
    out = {}
    for env_id, cfg in ENVS.items():
        raw = raw_rate(env_id, cfg, steps)
        env = env_rate(env_id, cfg, steps)
        out[env_id] = {"env_steps_per_s": env, "raw_frames_per_s": raw, "share_of_raw": env / raw}
    return out


def measure_old(rev: str, steps: int) -> dict[str, float]:
    """Env-steps/s of revision `rev` (its own simharness, this script's env loop) in a subprocess."""
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="simharness_old_") as tmp:
        wt = Path(tmp) / "wt"
        subprocess.run(["git", "-C", str(root), "worktree", "add", "--detach", str(wt), rev], check=True,
                       capture_output=True)
        try:
            code = ("import json, sys; sys.path.insert(0, sys.argv[1]); from envs_bench import env_rate, ENVS; "
                    f"print(json.dumps({{k: env_rate(k, c, {steps}) for k, c in ENVS.items()}}))")
            (Path(tmp) / "envs_bench.py").write_text(Path(__file__).read_text())
            env = {**os.environ, "PYTHONPATH": str(wt)}
            proc = subprocess.run([sys.executable, "-c", code, tmp], capture_output=True, text=True, env=env,
                                  cwd=wt, check=True)
            return json.loads(proc.stdout.strip().splitlines()[-1])
        finally:
            subprocess.run(["git", "-C", str(root), "worktree", "remove", "--force", str(wt)], capture_output=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=600)
    p.add_argument("--old", default=None, help="git revision to compare with")
    a = p.parse_args()
    res = measure(a.steps)
    old = measure_old(a.old, a.steps) if a.old else {}
    print(f"{'env':18s} {'env-steps/s':>12s} {'raw frames/s':>13s} {'share':>6s}" + (f" {'old env-steps/s':>16s}"
                                                                                    if old else ""))
    for k, r in res.items():
        line = f"{k:18s} {r['env_steps_per_s']:12.0f} {r['raw_frames_per_s']:13.0f} {r['share_of_raw']:6.0%}"
        if old:
            line += f" {old[k]:16.0f}"
        print(line)
    print(json.dumps({"now": res, "old": old}))


if __name__ == "__main__":
    main()
