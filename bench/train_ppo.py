"""PPO (stable-baselines3) on a simharness env at its default reward: the shipped learned planner baseline.

Trains on 4 envs in one process (`make_vec_env`, DummyVecEnv, Monitor logging each episode's return,
collisions and progress), stops at --steps or at the --deadline (UTC, HH:MM) whichever comes first,
checkpoints every --save-every steps, then writes

- the policy (SB3 zip) to --policy (default simharness/policies/ppo_highway_dense.zip) and beside it a
  JSON note of how it was made (command, seed, steps, wall time, versions, the full env config, which
  `simharness.policy_planner.load_policy_planner` reads back);
- the learning curve (episode return, collision shares and progress against env steps, 50-episode
  moving average) to --figure, its data to RUN/curve.json.

--action discrete (default) trains on the 12 meta-actions, continuous on the Box; --predictor NAME adds
the forecast observation (MultiInputPolicy).

Usage: OMP_NUM_THREADS=1 python bench/train_ppo.py [--steps 600000] [--deadline 14:10] [--seed 0]
                                                  [--env HighwayDense-v0] [--action discrete] [--predictor const-vel]
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

ROOT = Path(__file__).resolve().parents[1]
PPO_KWARGS = {"n_steps": 512, "batch_size": 128, "n_epochs": 5, "learning_rate": 3e-4, "gamma": 0.99,
              "gae_lambda": 0.95, "ent_coef": 0.01, "clip_range": 0.2}
MONITOR_KEYS = ("collided", "at_fault_collisions", "progress_m")


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
            "length": [int(r["l"]) for r in rows],
            "collided": [float(r["collided"] == "True") for r in rows],
            "at_fault": [float(float(r.get("at_fault_collisions", 0) or 0) > 0) for r in rows],
            "progress_m": [float(r["progress_m"]) for r in rows]}


def plot_curve(curve: dict[str, list[float]], path: Path, title: str = "PPO", window: int = 50) -> None:
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
    a.set_title(f"{title}: return")
    b.plot(steps[k - 1:], smooth(curve["collided"]), color="tab:red", label="collision share")
    if "at_fault" in curve:
        b.plot(steps[k - 1:], smooth(curve["at_fault"]), color="tab:red", ls="--", label="at-fault share")
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
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=600_000)
    p.add_argument("--env", default="HighwayDense-v0", choices=("HighwayDense-v0", "SumoDense-v0"))
    p.add_argument("--action", default="discrete", choices=("discrete", "continuous"))
    p.add_argument("--predictor", default=None, help="add the forecast observation from this predictor")
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

    import simharness.envs  # noqa: F401 - registers the ids

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

    env_id = f"simharness.envs:simharness/{a.env}"
    config = {"action": a.action, "predictor": a.predictor}
    venv = make_vec_env(env_id, n_envs=a.n_envs, seed=a.seed, monitor_dir=str(monitor_dir),
                        monitor_kwargs={"info_keywords": MONITOR_KEYS}, env_kwargs={"config": config})
    env_config = venv.envs[0].unwrapped.config
    policy = "MultiInputPolicy" if a.predictor else "MlpPolicy"
    model = PPO(policy, venv, seed=a.seed, verbose=0, device="cpu", **PPO_KWARGS)
    t0 = time.time()
    model.learn(total_timesteps=a.steps, callback=Budget())
    wall = time.time() - t0
    venv.close()

    a.policy.parent.mkdir(parents=True, exist_ok=True)
    model.save(a.policy)
    curve = load_curve(monitor_dir)
    (a.run / "curve.json").write_text(json.dumps(curve))
    plot_curve(curve, a.figure, f"PPO ({a.action}{', ' + a.predictor + ' forecasts' if a.predictor else ''}) "
                                f"on {a.env}")
    last = slice(-200, None)
    note = {
        "what": f"SB3 PPO {policy} trained on simharness/{a.env}, default reward, {a.action} actions"
                + (f", {a.predictor} forecast observation" if a.predictor else ""),
        "env": f"simharness/{a.env}",
        "command": "OMP_NUM_THREADS=1 python " + " ".join(sys.argv),
        "seed": a.seed, "n_envs": a.n_envs, "requested_steps": a.steps, "trained_steps": int(model.num_timesteps),
        "stopped_by": "steps" if model.num_timesteps >= a.steps else "deadline",
        "wall_s": round(wall, 1), "ppo": PPO_KWARGS, "env_config": env_config,
        "episodes": len(curve["return"]),
        "last_200_episodes": {"mean_return": float(np.mean(curve["return"][last])),
                              "collision_share": float(np.mean(curve["collided"][last])),
                              "at_fault_share": float(np.mean(curve["at_fault"][last])),
                              "mean_length": float(np.mean(curve["length"][last])),
                              "mean_progress_m": float(np.mean(curve["progress_m"][last]))},
        "versions": {"python": platform.python_version(), "stable_baselines3": stable_baselines3.__version__,
                     "torch": torch.__version__, "gymnasium": gymnasium.__version__, "numpy": np.__version__},
    }
    a.policy.with_suffix(".json").write_text(json.dumps(note, indent=2) + "\n")
    print(json.dumps(note["last_200_episodes"]), model.num_timesteps, "steps", f"{wall:.0f} s")


if __name__ == "__main__":
    main()
