"""PPO (stable-baselines3) on a simharness env at its default reward: the learned planner baseline.

Trains on 4 envs, one process each (`make_vec_env`, SubprocVecEnv; --vec dummy keeps them in this
process), Monitor logging each episode's return, collisions and progress, returns scaled by `VecNormalize`;
stops at --steps or at the --deadline (UTC HH:MM, or +SECONDS from the start) whichever comes first,
checkpoints every --save-every steps, then writes

- the policy (SB3 zip) to --policy (default RUN/ppo.zip; RUN is --run) and beside it a
  JSON note of how it was made (command, seed, steps, wall time, versions, the full env config, which
  `simharness.policy_planner.load_policy_planner` reads back);
- the learning curve (episode return, collision shares and progress against env steps, 50-episode
  moving average) to --figure (default RUN/curve.png), its data to RUN/curve.json.

--action speed (default) trains on the 12 target-speed meta-actions, follow on the same keeping IDM's gap to the
agent ahead, discrete on the acceleration ones, continuous on the Box; --no-lateral drops the meta-actions'
nudges (the line held); --predictor NAME adds the forecast observation (MultiInputPolicy).

Usage: OMP_NUM_THREADS=1 python bench/train_ppo.py [--steps 2000000] [--deadline 14:10|+3600] [--seed 0]
                                                  [--env HighwayDense-v0] [--action speed] [--predictor const-vel]
                                                  [--n-envs 4] [--vec subproc] [--reward ttc=0] [--no-lateral]
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
# bench/ holds a script named predictor.py: keep it from shadowing the `predictor` package (here and in the
# env processes, which start with this sys.path).
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# gamma 0.9 (a 2 s horizon at 5 Hz, highway-env's PPO examples use 0.8): long enough to brake for what is
# ahead, short enough that the value of driving is not drowned by a collision's steps * span penalty
PPO_KWARGS = {"n_steps": 512, "batch_size": 256, "n_epochs": 10, "learning_rate": 3e-4, "gamma": 0.9,
              "gae_lambda": 0.95, "ent_coef": 0.01, "clip_range": 0.2,
              "policy_kwargs": {"net_arch": {"pi": [256, 256], "vf": [256, 256]}}}
MONITOR_KEYS = ("collided", "at_fault_collisions", "progress_m")


def _deadline(text: str | None) -> float:
    """Seconds since the epoch of today's HH:MM UTC, or of +SECONDS from now (inf when not given)."""
    if not text:
        return float("inf")
    if text.startswith("+"):
        return time.time() + float(text[1:])
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


def plot_curves(curves: dict[str, dict[str, list[float]]], path: Path, window: int = 100) -> None:
    """Collision share and progress per episode against env steps of several runs (`window`-episode means)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.4))
    for label, curve in curves.items():
        k = max(1, min(window, len(curve["steps"])))
        steps = np.asarray(curve["steps"])[k - 1:]
        for ax, key in ((a, "collided"), (b, "progress_m")):
            ax.plot(steps, np.convolve(np.asarray(curve[key], float), np.ones(k) / k, mode="valid"), label=label)
    a.set_ylim(0, 1)
    a.set_ylabel(f"collision share ({window}-episode mean)")
    b.set_ylabel(f"progress (m, {window}-episode mean)")
    for ax in (a, b):
        ax.set_xlabel("env steps")
        ax.xaxis.set_major_formatter(plt.FuncFormatter(lambda x, _: f"{x / 1000:.0f}k"))
    a.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=2_000_000)
    p.add_argument("--env", default="HighwayDense-v0", choices=("HighwayDense-v0", "SumoDense-v0"))
    p.add_argument("--action", default="speed", choices=("speed", "follow", "discrete", "continuous"))
    p.add_argument("--predictor", default=None, help="add the forecast observation from this predictor")
    p.add_argument("--no-lateral", action="store_true", help="meta-actions without the nudges (the line held)")
    p.add_argument("--reward", action="append", default=[], metavar="TERM=WEIGHT",
                   help="a reward weight other than the default, e.g. ttc=0 (repeatable)")
    p.add_argument("--deadline", default=None, help="stop at this UTC time (HH:MM) or after +SECONDS if not done")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-envs", type=int, default=4)
    p.add_argument("--vec", default="subproc", choices=("subproc", "dummy"),
                   help="subproc: one process per env (uses every core); dummy: all envs in this process")
    p.add_argument("--save-every", type=int, default=20_480, help="checkpoint period (steps; 10 rollouts)")
    p.add_argument("--keep-checkpoints", action="store_true", help="also keep each as RUN/checkpoints/STEPS.zip")
    p.add_argument("--run", type=Path, default=ROOT / "runs" / "ppo_highway_dense")
    p.add_argument("--resume", type=Path, default=None, help="go on training this zip (bench/train_ppo.py's)")
    p.add_argument("--policy", type=Path, default=None, help="default RUN/ppo.zip (copy it to "
                   "simharness/policies/ppo_highway_dense.zip, with its .json, to ship it)")
    p.add_argument("--figure", type=Path, default=None, help="default RUN/curve.png")
    p.add_argument("--plot", nargs="+", metavar=("FIGURE", "LABEL=CURVE.json"),
                   help="only plot the curve.json of several runs into FIGURE, then exit")
    a = p.parse_args()
    a.policy = a.policy or a.run / "ppo.zip"
    a.figure = a.figure or a.run / "curve.png"
    if a.plot:
        plot_curves({x.partition("=")[0]: json.loads(Path(x.partition("=")[2]).read_text()) for x in a.plot[1:]},
                    Path(a.plot[0]))
        return

    import gymnasium
    import stable_baselines3
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    import simharness.envs  # noqa: F401 - registers the ids

    torch.set_num_threads(1)
    a.run.mkdir(parents=True, exist_ok=True)
    monitor_dir = a.run / "monitor"
    for old in monitor_dir.glob("*.monitor.csv"):
        old.unlink()

    class Budget(BaseCallback):
        """Stop at the deadline; checkpoint every save_every steps (the policy so far survives a kill)."""

        def __init__(self) -> None:
            super().__init__()
            self.next_save = a.save_every

        def _on_training_start(self) -> None:  # a resumed run saves at the next multiple of save_every
            self.next_save = (self.num_timesteps // a.save_every + 1) * a.save_every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_save:
                self.model.save(a.run / "checkpoint.zip")
                if a.keep_checkpoints:  # for comparisons at equal steps with a slower variant
                    self.model.save(a.run / "checkpoints" / f"{self.next_save}.zip")
                self.next_save += a.save_every
                print(f"{time.strftime('%H:%M:%S')} {self.num_timesteps} steps", flush=True)
            return time.time() < end_at

    env_id = f"simharness.envs:simharness/{a.env}"
    config = {"action": a.action, "predictor": a.predictor, "lateral": not a.no_lateral}
    if a.reward:
        config["reward"] = {k: float(v) for k, _, v in (x.partition("=") for x in a.reward)}
    venv = make_vec_env(env_id, n_envs=a.n_envs, seed=a.seed, monitor_dir=str(monitor_dir),
                        monitor_kwargs={"info_keywords": MONITOR_KEYS}, env_kwargs={"config": config},
                        vec_env_cls=SubprocVecEnv if a.vec == "subproc" else DummyVecEnv)
    env_config = venv.get_attr("config")[0]
    # returns scaled to unit spread (the Monitor logs the raw ones); observations are in [-1, 1] already, so
    # the saved policy needs no statistics to run
    venv = VecNormalize(venv, norm_obs=False, norm_reward=True, gamma=PPO_KWARGS["gamma"])
    policy = "MultiInputPolicy" if a.predictor else "MlpPolicy"
    if a.resume:  # our own zip: go on from its weights and step count (a fresh optimizer)
        model = PPO.load(a.resume, env=venv, device="cpu")
        model.set_random_seed(a.seed)
    else:
        model = PPO(policy, venv, seed=a.seed, verbose=0, device="cpu", **PPO_KWARGS)
    start = int(model.num_timesteps)
    end_at = _deadline(a.deadline)  # +SECONDS count from here, once the env processes are up
    t0 = time.time()
    model.learn(total_timesteps=a.steps - start, callback=Budget(), reset_num_timesteps=not a.resume)
    wall = time.time() - t0
    venv.close()

    a.policy.parent.mkdir(parents=True, exist_ok=True)
    model.policy.optimizer.state.clear()  # Adam's moments only serve further training: the shipped zip stays small
    model.save(a.policy)
    curve = load_curve(monitor_dir)
    curve["steps"] = [start + n for n in curve["steps"]]
    (a.run / "curve.json").write_text(json.dumps(curve))
    if curve["return"]:
        plot_curve(curve, a.figure, f"PPO ({a.action}{', ' + a.predictor + ' forecasts' if a.predictor else ''}) "
                                    f"on {a.env}")
    last = slice(-200, None)
    note = {
        "what": f"SB3 PPO {policy} trained on simharness/{a.env}, "
                f"{'reward ' + ', '.join(a.reward) if a.reward else 'default reward'}, {a.action} actions"
                + (f", {a.predictor} forecast observation" if a.predictor else ""),
        "env": f"simharness/{a.env}",
        "command": "OMP_NUM_THREADS=1 python " + " ".join(sys.argv),
        "seed": a.seed, "n_envs": a.n_envs, "vec": a.vec, "requested_steps": a.steps,
        "trained_steps": int(model.num_timesteps), "resumed_from": str(a.resume) if a.resume else None,
        "resumed_at_steps": start,
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
