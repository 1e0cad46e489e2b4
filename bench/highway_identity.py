"""Same seeds, same arrays: the highway backend and HighwayDense-v0 of this tree against a git revision.

Records, in a subprocess per tree, (1) a rollout of every highway scenario (highway_mixed_dense,
highway_ngsim_like, scenarios/stress/*) under each ego reaction (reactive, ignore, cut_in) with seeded
random ego commands, a branch stepped with other commands, and a restart of the ego; (2) HighwayDense-v0
under a seeded random policy, resets included. Every frame's arrays and the traffic state (float64 x, y,
vx, vy, y_target, uids) after each frame are kept, then compared byte for byte (signs of zeros included).
A speed-up of the backend must leave this at "identical".

Usage: python bench/highway_identity.py [--old REV] [--frames 40] [--env-steps 400]
  --old REV  the revision to compare with (checked out into a temporary worktree); default HEAD.
Exit status 1 when any array differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")

SCENARIOS = ("highway_mixed_dense", "highway_ngsim_like", "stress/brake", "stress/cut_in", "stress/merge",
             "stress/pull_out", "stress/step_out")
REACTIONS = ("reactive", "ignore", "cut_in")


def _frame_arrays(prefix: str, frame, sim) -> dict[str, np.ndarray]:  # noqa: ANN001 - Frame, HighwaySimulator
    s = sim.traffic.state
    out = {f"{prefix}/{k}": np.asarray(getattr(frame, k)) for k in ("xy", "heading", "speed", "length", "width",
                                                                     "agent_type")}
    out[f"{prefix}/agent_id"] = frame.agent_id.astype(str)
    out[f"{prefix}/ego"] = np.array(frame.ego)
    out[f"{prefix}/events"] = np.array([f"{e.kind}:{e.agent_id}:{e.other_id}:{e.t!r}" for e in frame.events], str)
    for k in ("uid", "x", "y", "vx", "vy", "y_target"):
        out[f"{prefix}/state.{k}"] = getattr(s, k).copy()
    return out


def record(frames: int, env_steps: int) -> dict[str, np.ndarray]:
    """All arrays of the rollouts, keyed by where they come from (run in the tree under test)."""
    from simharness.scenario import load_scenario
    from simharness.sim import EgoCommand, make_simulator

    out: dict[str, np.ndarray] = {}
    for name in SCENARIOS:
        for reaction in REACTIONS:
            spec = load_scenario(name).with_overrides({"ego.enabled": True, "ego.reaction": reaction,
                                                       "ego.insert_at": 0.0})
            sim = make_simulator(spec)
            rng = np.random.default_rng(7)
            key = f"{name}/{reaction}"
            out.update(_frame_arrays(f"{key}/0", sim.reset(3), sim))

            def command(rng: np.random.Generator) -> EgoCommand | None:
                if rng.random() < 0.15:
                    return None  # the ego drives like the background now and then
                return EgoCommand(float(rng.uniform(-6.0, 3.0)), float(rng.uniform(-1.5, 1.5)))

            branch = None
            for t in range(1, frames + 1):
                out.update(_frame_arrays(f"{key}/{t}", sim.step(command(rng)), sim))
                if t == frames // 2:
                    branch = sim.branch()
            brng = np.random.default_rng(11)
            for t in range(1, frames // 2 + 1):
                out.update(_frame_arrays(f"{key}/branch/{t}", branch.step(command(brng)), branch))
            out.update(_frame_arrays(f"{key}/restart/0", sim.restart_ego(), sim))
            for t in range(1, frames // 4 + 1):
                out.update(_frame_arrays(f"{key}/restart/{t}", sim.step(command(rng)), sim))
            sim.close()

    import gymnasium as gym

    import simharness.envs  # noqa: F401 - registers the ids

    env = gym.make("simharness/HighwayDense-v0")
    env.action_space.seed(5)
    obs, _ = env.reset(seed=5)
    out["env/reset/0"] = obs
    resets = 0
    for t in range(env_steps):
        obs, reward, term, trunc, info = env.step(env.action_space.sample())
        out[f"env/{t}/obs"] = obs
        out[f"env/{t}/step"] = np.array([reward, term, trunc, *[float(v) for v in info.values()]])
        if term or trunc:
            resets += 1
            obs, _ = env.reset()
            out[f"env/reset/{resets}"] = obs
    env.close()
    return out


def record_tree(root: Path, frames: int, env_steps: int, dest: Path) -> None:
    """`record` in a subprocess that imports simharness from `root`; arrays saved to dest (.npz)."""
    code = ("import sys, numpy as np; sys.path.insert(0, sys.argv[1]); from highway_identity import record; "
            "np.savez(sys.argv[2], **record(int(sys.argv[3]), int(sys.argv[4])))")
    env = {**os.environ, "PYTHONPATH": str(root)}
    subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent), str(dest), str(frames), str(env_steps)],
                   env=env, cwd=root, check=True)


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[str]:
    """Keys whose arrays differ in keys, dtype, shape or bytes (so -0.0 != 0.0 and NaNs compare by bits)."""
    bad = sorted(set(a) ^ set(b))
    for k in sorted(set(a) & set(b)):
        x, y = a[k], b[k]
        if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
            bad.append(k)
    return bad


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--old", default="HEAD", help="git revision to compare with")
    p.add_argument("--frames", type=int, default=40, help="recorded frames per scenario and reaction")
    p.add_argument("--env-steps", type=int, default=400, help="random-policy steps of HighwayDense-v0")
    a = p.parse_args()
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="simharness_identity_") as tmp:
        wt = Path(tmp) / "old"
        subprocess.run(["git", "-C", str(root), "worktree", "add", "--detach", str(wt), a.old], check=True,
                       capture_output=True)
        try:
            record_tree(root, a.frames, a.env_steps, Path(tmp) / "new.npz")
            record_tree(wt, a.frames, a.env_steps, Path(tmp) / "old.npz")
        finally:
            subprocess.run(["git", "-C", str(root), "worktree", "remove", "--force", str(wt)], capture_output=True)
        with np.load(Path(tmp) / "new.npz") as f_new, np.load(Path(tmp) / "old.npz") as f_old:
            new, old = dict(f_new), dict(f_old)
    bad = compare(new, old)
    n_values = sum(v.size for v in new.values())
    print(f"{len(new)} arrays ({n_values} values) against {a.old}: "
          + ("identical" if not bad else f"{len(bad)} differ, first: {', '.join(bad[:8])}"))
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
