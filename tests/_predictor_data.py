"""Small synthetic data sets for predictor tests, written through the real Parquet layer."""

from pathlib import Path

import numpy as np

from simharness.io.parquet import write_dataset
from simharness.scene import AgentType, Scene


def flow_scene(seed: int, n: int = 16, t: int = 70, dt: float = 0.2) -> Scene:
    """Mixed agents driving along x with gentle curves and speed changes (learnable, not constant velocity)."""
    rng = np.random.default_rng(seed)
    time = np.arange(t) * dt
    v0 = rng.uniform(2, 10, n)
    acc = rng.uniform(-0.6, 0.6, n)
    speed = np.clip(v0[:, None] + acc[:, None] * time, 0.5, None)
    head = 0.15 * np.sin(0.3 * time[None] + rng.uniform(0, 6, n)[:, None])
    xy = np.cumsum(np.stack([np.cos(head), np.sin(head)], -1) * speed[..., None] * dt, 1)
    xy += np.stack([rng.uniform(0, 60, n), rng.uniform(-6, 6, n)], -1)[:, None]
    types = rng.integers(0, 8, n)
    fp = np.array([AgentType(int(k)).footprint for k in types])
    return Scene(xy=xy, heading=head, speed=speed, valid=np.ones((n, t), bool), agent_id=[f"v{i}" for i in range(n)],
                 agent_type=types, length=fp[:, 0], width=fp[:, 1], dt=dt, meta={"scenario": "test-flow", "seed": seed})


def write_flow_dataset(out: Path, scenes: int = 5) -> Path:
    write_dataset([flow_scene(s) for s in range(scenes)], out, {"source": "tests/_predictor_data.py"})
    return out


def fit_steps(net, batch: dict, opt, steps: int) -> None:
    """`steps` MSE steps of `net` on one batch (a model's own `training_step` when it has one, e.g. Social-GAN)."""
    from predictor.losses import mse

    for _ in range(steps):
        if hasattr(net, "training_step"):
            net.training_step(batch, "mse", opt)
        else:
            loss = mse(net(batch), batch["fut"], batch["fut_valid"])
            opt.zero_grad()
            loss.backward()
            opt.step()
