"""Imitation of the prediction-driven planner (behaviour cloning + DAgger): a learned baseline that drives.

The expert is the default `PDMPlanner` fed constant-velocity forecasts, run in the closed loop
(`simharness.closedloop.simulate`) on training seeds only (0-99; the scored seeds are 100+). At every
planning step the observation an SB3 policy would see (built by `PolicyPlanner`, exactly as in the env
and in `simharness closedloop --planner`) is recorded with the expert's command, turned into the env's
continuous Box action (`command_to_action`, the inverse of the env's action map).

- iteration 0: the expert drives (behaviour cloning data);
- iterations 1..R (DAgger): the learned policy drives (iteration r hands each step to the expert with probability
  --beta ** r), the expert labels every state it reaches; the data are aggregated and the policy refitted.

The policy is an SB3 `PPO` actor-critic (MlpPolicy, or MultiInputPolicy with --predictor's forecast
observation); its Gaussian mean is fitted to the expert's actions by squared error (plain torch over
`model.policy`), the acceleration's by an expectile (--caution) that leans to braking when below 0.5;
--straight labels every lateral speed 0 (the policy imitates the planner's acceleration only).
Writes --policy (an SB3 zip that `simharness closedloop SCENARIO --planner PATH.zip` drives) and beside it a
JSON note (command, seed, samples per iteration, wall time, versions, env config), each iteration's policy as
RUN/iterationR.zip (+ .json), and RUN/iterations.json with each iteration's driving (collision share, progress) on its
training seeds.

Usage: OMP_NUM_THREADS=1 python bench/train_imitation.py [--scenarios highway_mixed_dense] [--episodes 16]
          [--iterations 3] [--beta 0.5] [--duration 30] [--caution 0.5] [--straight] [--predictor const-vel]
          [--seed 0] [--workers 2] [--run runs/imitation] [--policy RUN/policy.zip]
          [--plot FIGURE LABEL=ITERATIONS.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
# bench/ holds a script named predictor.py: keep it from shadowing the `predictor` package.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

from simharness.envs.actions import command_to_action  # noqa: E402
from simharness.envs.config import DEFAULT_CONFIG, resolve_config  # noqa: E402
from simharness.policy_planner import PolicyPlanner  # noqa: E402
from simharness.scene import Forecast, Scene  # noqa: E402
from simharness.sim.base import EgoCommand  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NET_ARCH = {"pi": [256, 256], "vf": [256, 256]}
LOG_STD = -1.6  # the Gaussian's spread (std 0.2): only a stochastic rollout or PPO fine-tuning uses it


class Recorder:
    """A `Policy` that keeps the last observation it was asked about; answers with `inner` (zeros if None)."""

    def __init__(self, inner: Any = None) -> None:
        self.inner = inner
        self.obs: Any = None

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:
        self.obs = observation
        if self.inner is None:
            return np.zeros(2, np.float32), None
        return self.inner.predict(observation, deterministic=deterministic)


class LabellingPlanner:
    """A `Planner` that records (policy observation, expert action) at every step while the expert drives
    (`beta` = 1), the student drives (0), or each step is the expert's with probability `beta`."""

    def __init__(self, expert: Any, student: Any, config: dict[str, Any], beta: float, seed: int,
                 straight: bool = False) -> None:
        self.expert, self.config, self.beta, self.straight = expert, config, beta, straight
        self.recorder = Recorder(student)
        self.student = PolicyPlanner(self.recorder, config)
        self.rng = np.random.default_rng(seed)
        self.reset()

    def reset(self) -> None:
        self.expert.reset()
        self.student.reset()
        self.obs: list[Any] = []
        self.actions: list[np.ndarray] = []
        self.ended = False

    def set_road(self, road: Any) -> None:
        self.expert.set_road(road)

    def plan(self, now: Scene, forecast: Forecast | None) -> EgoCommand | None:
        label = self.expert.plan(now, forecast)
        self.recorder.obs = None
        own = self.student.plan(now, forecast)
        if self.recorder.obs is not None and label is not None:
            self.obs.append(self.recorder.obs)
            action = command_to_action(label, self.config)
            if self.straight:  # only the acceleration is imitated; the policy holds its line
                action[1] = 0.0
            self.actions.append(action)
        if self.beta >= 1.0 or (own is not None and self.rng.random() < self.beta):
            return label
        self.ended = self.student.ended  # the student's episode ends at its collision, as when it is scored
        return own


def rollout(job: dict[str, Any]) -> dict[str, Any]:
    """One labelled closed-loop episode (a worker's job): observations, expert actions and how it went."""
    import torch

    from simharness.closedloop import prepare_spec
    from simharness.closedloop.config import LoopConfig
    from simharness.closedloop.episode import make_planner, simulate
    from simharness.closedloop.scoring import score_episode
    from simharness.plugins import load_predictor
    from simharness.policy_planner import load_policy
    from simharness.scenario import load_scenario

    torch.set_num_threads(1)
    spec = load_scenario(job["scenario"])
    spec = prepare_spec(spec.with_overrides({"duration": job["duration"]}) if job["duration"] else spec)
    config = job["config"]
    student = load_policy(Path(job["student"]), config) if job["student"] else None
    expert = make_planner("const-vel", spec, None)  # the default planner, as the prediction-driven egos drive
    planner = LabellingPlanner(expert, student, config, job["beta"], job["seed"], job.get("straight", False))
    cfg = LoopConfig()
    scene, issued, _, _ = simulate(spec, job["seed"], load_predictor("const-vel"), planner, cfg)
    scores = score_episode(scene, issued, cfg)
    return {"obs": planner.obs, "act": np.asarray(planner.actions, np.float32).reshape(-1, 2),
            "scenario": job["scenario"], "seed": job["seed"], "collided": bool(scores["collided"]),
            "at_fault": bool(scores["at_fault_collided"]),
            "progress_m": float(scores["progress_m"])}


def stack(obs: list[Any]) -> Any:
    """Observations -> one (N, ...) float32 array, or a dict of them for a Dict observation."""
    if isinstance(obs[0], dict):
        return {k: np.stack([o[k] for o in obs]).astype(np.float32) for k in obs[0]}
    return np.stack(obs).astype(np.float32)


def make_model(config: dict[str, Any], seed: int) -> Any:
    """An untrained SB3 PPO actor-critic on the env's spaces (a stub env: only its spaces are used)."""
    import gymnasium
    from stable_baselines3 import PPO

    from simharness.envs.actions import action_space
    from simharness.envs.dense import observation_space

    class Spaces(gymnasium.Env):
        def __init__(self) -> None:
            self.observation_space, self.action_space = observation_space(config), action_space(config)

    policy = "MultiInputPolicy" if config["predictor"] else "MlpPolicy"
    model = PPO(policy, Spaces(), seed=seed, device="cpu", policy_kwargs={"net_arch": NET_ARCH})
    model.policy.log_std.data.fill_(LOG_STD)
    return model


def fit(model: Any, obs: Any, act: np.ndarray, epochs: int, lr: float, batch: int, seed: int,
        caution: float = 0.5) -> float:
    """Fit the policy's Gaussian mean to `act` (N, 2) by squared error, `epochs` passes of Adam; the last epoch's
    mean loss. caution: the acceleration's expectile (0.5: plain MSE; below it an acceleration above the
    expert's costs more than one below, so the fit leans to braking, where a miss is a collision)."""
    import torch

    policy = model.policy
    policy.set_training_mode(True)
    params = [p for n, p in policy.named_parameters() if n != "log_std" and "value_net" not in n
              and "mlp_extractor.value" not in n]
    opt = torch.optim.Adam(params, lr=lr)
    gen = torch.Generator().manual_seed(seed)
    as_t = (lambda o, i: {k: torch.as_tensor(v[i]) for k, v in o.items()}) if isinstance(obs, dict) else \
        (lambda o, i: torch.as_tensor(o[i]))
    target = torch.as_tensor(act)
    loss_sum = 0.0
    for _ in range(epochs):
        loss_sum, perm = 0.0, torch.randperm(len(act), generator=gen)
        for idx in perm.split(batch):
            i = idx.numpy()
            mean = policy.get_distribution(as_t(obs, i)).distribution.mean
            err = mean - target[idx]
            weight = torch.ones_like(err)
            weight[:, 0] = torch.where(err[:, 0] > 0, 1.0 - caution, caution) * 2.0  # 1 for both at 0.5
            loss = (weight * err**2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            loss_sum += float(loss.detach()) * len(idx)
    policy.set_training_mode(False)
    return loss_sum / len(act)


def save(model: Any, path: Path, note: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    model.policy.optimizer.state.clear()  # Adam's moments only serve further training: the zip stays small
    model.save(path)
    path.with_suffix(".json").write_text(json.dumps(note, indent=2) + "\n")


def plot_iterations(runs: dict[str, list[dict[str, Any]]], path: Path) -> None:
    """Collision share and mean progress of each iteration's training episodes, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.4))
    for label, iterations in runs.items():
        x = [r["iteration"] for r in iterations]
        left.plot(x, [r["collision_share"] for r in iterations], "o-", label=label)
        right.plot(x, [r["mean_progress_m"] for r in iterations], "o-", label=label)
    left.set_ylim(0, 1)
    left.set_ylabel("collision share of the iteration's episodes")
    right.set_ylabel("progress per episode (m)")
    for ax in (left, right):
        ax.set_xlabel("iteration (0: the expert drives; then the policy, DAgger)")
    left.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def note(a: argparse.Namespace, scenarios: list[str], config: dict[str, Any], iterations: list[dict[str, Any]],
         samples: int, wall: float) -> dict[str, Any]:
    """The JSON note beside a policy: how it was made (`load_policy_planner` reads its "env_config")."""
    import gymnasium
    import stable_baselines3
    import torch

    return {
        "what": "SB3 PPO " + ("MultiInputPolicy" if a.predictor else "MlpPolicy") + " actor trained by imitation "
                "(behaviour cloning + DAgger) of the prediction-driven planner (PDMPlanner, const-vel forecasts), "
                "continuous actions" + (f", {a.predictor} forecast observation" if a.predictor else ""),
        "env": "simharness/HighwayDense-v0",
        "command": "OMP_NUM_THREADS=1 python " + " ".join(sys.argv),
        "seed": a.seed, "scenarios": scenarios, "training_seeds": f"0-{min(len(iterations) * a.episodes, 100) - 1}",
        "episode_s": a.duration, "iterations": iterations, "samples": samples,
        "trained_steps": samples,  # closed-loop steps labelled by the expert (the data the policy was fitted on)
        "epochs": a.epochs, "caution": a.caution, "straight": a.straight,
        "lr": a.lr, "batch": a.batch, "net_arch": NET_ARCH, "workers": a.workers, "wall_s": round(wall, 1),
        "env_config": config,
        "versions": {"python": platform.python_version(), "stable_baselines3": stable_baselines3.__version__,
                     "torch": torch.__version__, "gymnasium": gymnasium.__version__, "numpy": np.__version__},
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenarios", default="highway_mixed_dense", help="comma list of training scenarios")
    p.add_argument("--episodes", type=int, default=16, help="episodes per scenario per iteration")
    p.add_argument("--iterations", type=int, default=3,
                   help="DAgger iterations after the expert's (behaviour cloning) one")
    p.add_argument("--beta", type=float, default=0.5, help="iteration r: share beta ** r of steps the expert drives")
    p.add_argument("--duration", type=float, default=30.0, help="s per training episode (0: the scenario's)")
    p.add_argument("--predictor", default=None, help="add the forecast observation from this predictor")
    p.add_argument("--epochs", type=int, default=30, help="passes over the aggregated data per iteration")
    p.add_argument("--caution", type=float, default=0.5, help="expectile of the acceleration fit (0.5: MSE; "
                   "lower leans to braking)")
    p.add_argument("--straight", action="store_true", help="label lateral speed 0: imitate the acceleration only")
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--run", type=Path, default=ROOT / "runs" / "imitation")
    p.add_argument("--policy", type=Path, default=None, help="default RUN/policy.zip (copy it to "
                   "simharness/policies/ppo_highway_dense.zip, with its .json, to ship it)")
    p.add_argument("--plot", nargs="+", metavar=("FIGURE", "LABEL=ITERATIONS.json"),
                   help="only plot the iterations.json of several runs into FIGURE, then exit")
    a = p.parse_args()
    if a.plot:
        plot_iterations({x.partition("=")[0]: json.loads(Path(x.partition("=")[2]).read_text()) for x in a.plot[1:]},
                    Path(a.plot[0]))
        return
    a.policy = a.policy or a.run / "policy.zip"
    scenarios = [s for s in a.scenarios.split(",") if s]
    if a.episodes > 100:
        p.error("--episodes: at most the 100 training seeds 0-99")

    import torch

    torch.manual_seed(a.seed)
    torch.set_num_threads(1)
    config = resolve_config(DEFAULT_CONFIG, {"scenario": scenarios[0], "predictor": a.predictor,
                                             "action": "continuous", "duration": a.duration or 60.0},
                            "train_imitation")
    model = make_model(config, a.seed)
    a.run.mkdir(parents=True, exist_ok=True)
    obs: list[Any] = []
    act: list[np.ndarray] = []
    iterations = []
    t0 = time.time()
    with ProcessPoolExecutor(a.workers, mp_context=get_context("spawn")) as pool:
        for r in range(a.iterations + 1):
            # the next training seeds each iteration, cycling through 0-99 (the policy drives them differently)
            seeds = [(r * a.episodes + i) % 100 for i in range(a.episodes)]
            beta = 1.0 if r == 0 else a.beta ** r  # the expert's share of the steps decays each iteration
            student = str(a.run / f"iteration{r - 1}.zip") if r else None
            jobs = [{"scenario": s, "seed": seed, "duration": a.duration, "config": config, "student": student,
                     "beta": beta, "straight": a.straight} for s in scenarios for seed in seeds]
            done = list(pool.map(rollout, jobs))
            for d in done:
                obs += d["obs"]
                act.append(d["act"])
            loss = fit(model, stack(obs), np.concatenate(act), a.epochs, a.lr, a.batch, a.seed + r, a.caution)
            row = {"iteration": r, "driver": "expert" if r == 0 else f"policy (expert share {beta:.3f})",
                   "episodes": len(done), "samples": len(obs), "train_loss": loss,
                   "collision_share": float(np.mean([d["collided"] for d in done])),
                   "at_fault_share": float(np.mean([d["at_fault"] for d in done])),
                   "mean_progress_m": float(np.mean([d["progress_m"] for d in done])),
                   "wall_s": round(time.time() - t0, 1)}
            iterations.append(row)
            print(json.dumps(row), flush=True)
            # every iteration's policy, loadable with its note: a run stopped early still leaves one
            save(model, a.run / f"iteration{r}.zip", note(a, scenarios, config, iterations, len(obs), time.time() - t0))
    times = os.times()  # the workers' CPU time is counted once the pool has closed
    cpu = times.user + times.system + times.children_user + times.children_system
    (a.run / "iterations.json").write_text(json.dumps(iterations, indent=2) + "\n")
    meta = note(a, scenarios, config, iterations, len(obs), time.time() - t0)
    save(model, a.policy, {**meta, "cpu_s": round(cpu, 1)})
    print(f"{len(obs)} samples, {time.time() - t0:.0f} s wall, {cpu:.0f} CPU-s -> {a.policy}")


if __name__ == "__main__":
    main()
