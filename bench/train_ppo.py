"""PPO (stable-baselines3) on HighwayDense-v0 with the default config: the planner baseline of issue 12.

Trains on 4 envs in one process (`make_vec_env`, DummyVecEnv, Monitor logging each episode's return,
collision and progress), stops at --steps or at the --deadline (UTC, HH:MM) whichever comes first,
checkpoints every --save-every steps, then writes

- the policy (SB3 zip) to --policy (default simharness/policies/ppo_highway_dense.zip) and beside it a
  JSON note of how it was made (command, seed, steps, wall time, versions, env config);
- the learning curve (episode return and collision share against env steps, 50-episode moving
  average) to docs/figures/ppo_highway_dense.png, its data to runs/ppo_highway_dense/curve.json.

Usage: OMP_NUM_THREADS=1 python bench/train_ppo.py [--steps 200000] [--deadline 12:25] [--seed 0]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ENV_ID = "simharness.envs:simharness/HighwayDense-v0"
ROOT = Path(__file__).resolve().parents[1]
PPO_KWARGS = {"n_steps": 512, "batch_size": 128, "n_epochs": 5, "learning_rate": 3e-4, "gamma": 0.99,
              "gae_lambda": 0.95, "ent_coef": 0.0, "clip_range": 0.2}


def _deadline(text: str | None) -> float:
    """Seconds since the epoch of today's HH:MM UTC (inf when not given)."""
    if not text:
        return float("inf")
    h, m = (int(x) for x in text.split(":"))
    now = dt.datetime.now(dt.timezone.utc)
    return now.replace(hour=h, minute=m, second=0, microsecond=0).timestamp()


def load_curve(monitor_dir: Path) -> dict[str, list[float]]:
    """Episodes from the Monitor CSVs in time order: env steps at the end, return, collided, progress (m)."""
    rows = []
    for f in sorted(monitor_dir.glob("*.monitor.csv")):
        lines = f.read_text().splitlines()[1:]  # first line: a JSON header
        head = lines[0].split(",")
        for line in lines[1:]:
            rows.append(dict(zip(head, line.split(","), strict=True)))
    rows.sort(key=lambda r: float(r["t"]))
    steps = np.cumsum([int(r["l"]) for r in rows])
    return {"steps": steps.tolist(), "return": [float(r["r"]) for r in rows],
            "collided": [float(r["collided"] == "True") for r in rows],
            "progress_m": [float(r["progress_m"]) for r in rows]}


def plot_curve(curve: dict[str, list[float]], path: Path, window: int = 50) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def smooth(x: list[float]) -> np.ndarray:
        x = np.asarray(x, float)
        k = max(1, min(window, len(x)))
        return np.convolve(x, np.ones(k) / k, mode="valid")

    steps = np.asarray(curve["steps"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.4))
    k = max(1, min(window, len(steps)))
    a.plot(steps, curve["return"], ".", ms=2, alpha=0.25, color="tab:blue")
    a.plot(steps[k - 1:], smooth(curve["return"]), color="navy", label=f"return ({k}-episode mean)")
    a.set_xlabel("env steps")
    a.set_ylabel("episode return")
    a.set_title("PPO on HighwayDense-v0: return")
    b.plot(steps[k - 1:], smooth(curve["collided"]), color="tab:red", label="collision share")
    b.set_ylim(0, 1)
    b.set_xlabel("env steps")
    b.set_ylabel(f"share of episodes ({k}-episode mean)")
    b2 = b.twinx()
    b2.plot(steps[k - 1:], smooth(curve["progress_m"]), color="tab:green", label="progress (m)")
    b2.set_ylabel("progress per episode (m)")
    b.set_title("collisions and progress")
    for ax in (a, b):  # "200k", not 200000: the full numbers overlap
        ax.xaxis.set_major_formatter(plt.FuncFormatter(lambda x, _: f"{x / 1000:.0f}k"))
    fig.legend(loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=200_000)
    p.add_argument("--deadline", default=None, help="stop at this UTC time (HH:MM) if not done")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-envs", type=int, default=4)
    p.add_argument("--save-every", type=int, default=20_000)
    p.add_argument("--run", type=Path, default=ROOT / "runs" / "ppo_highway_dense")
    p.add_argument("--policy", type=Path, default=ROOT / "simharness" / "policies" / "ppo_highway_dense.zip")
    p.add_argument("--figure", type=Path, default=ROOT / "docs" / "figures" / "ppo_highway_dense.png")
    a = p.parse_args()

    import gymnasium
    import stable_baselines3
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    import simharness.envs  # noqa: F401

    torch.set_num_threads(1)
    a.run.mkdir(parents=True, exist_ok=True)
    monitor_dir = a.run / "monitor"
    for old in monitor_dir.glob("*.monitor.csv"):
        old.unlink()
    end_at = _deadline(a.deadline)

    class Budget(BaseCallback):
        """Stop at the deadline; checkpoint every save_every steps (the policy so far survives a kill)."""

        def __init__(self) -> None:
            super().__init__()
            self.next_save = a.save_every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_save:
                self.model.save(a.run / "checkpoint.zip")
                self.next_save += a.save_every
                print(f"{time.strftime('%H:%M:%S')} {self.num_timesteps} steps", flush=True)
            return time.time() < end_at

    venv = make_vec_env(ENV_ID, n_envs=a.n_envs, seed=a.seed, monitor_dir=str(monitor_dir),
                        monitor_kwargs={"info_keywords": ("collided", "progress_m")})
    model = PPO("MlpPolicy", venv, seed=a.seed, verbose=0, device="cpu", **PPO_KWARGS)
    t0 = time.time()
    model.learn(total_timesteps=a.steps, callback=Budget())
    wall = time.time() - t0
    venv.close()

    a.policy.parent.mkdir(parents=True, exist_ok=True)
    model.save(a.policy)
    curve = load_curve(monitor_dir)
    (a.run / "curve.json").write_text(json.dumps(curve))
    plot_curve(curve, a.figure)
    last = slice(-200, None)
    note = {
        "what": "SB3 PPO MlpPolicy trained on simharness/HighwayDense-v0, default env config",
        "command": "OMP_NUM_THREADS=1 python " + " ".join(sys.argv),
        "seed": a.seed, "n_envs": a.n_envs, "requested_steps": a.steps, "trained_steps": int(model.num_timesteps),
        "stopped_by": "steps" if model.num_timesteps >= a.steps else "deadline",
        "wall_s": round(wall, 1), "ppo": PPO_KWARGS, "env_config": simharness.envs.HighwayDenseEnv.default_config(),
        "episodes": len(curve["return"]),
        "last_200_episodes": {"mean_return": float(np.mean(curve["return"][last])),
                              "collision_share": float(np.mean(curve["collided"][last])),
                              "mean_progress_m": float(np.mean(curve["progress_m"][last]))},
        "versions": {"python": platform.python_version(), "stable_baselines3": stable_baselines3.__version__,
                     "torch": torch.__version__, "gymnasium": gymnasium.__version__, "numpy": np.__version__},
    }
    a.policy.with_suffix(".json").write_text(json.dumps(note, indent=2) + "\n")
    print(json.dumps(note["last_200_episodes"]), model.num_timesteps, "steps", f"{wall:.0f} s")


if __name__ == "__main__":
    main()
