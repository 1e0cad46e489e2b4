"""A predictor plug-in with a small torch model: constant velocity plus a learned velocity correction.

An MLP reads a target's last 5 velocities in its own frame (x along its heading, y to its left) and
corrects its current velocity; the forecast extrapolates the corrected velocity, with a learned
position sigma growing linearly with time. Its last layer starts at zero, so the untrained model is
constant velocity. Train it on a data set (about a minute of CPU for 4 scenes of 60 s), then evaluate it:

    python examples/tiny_torch.py --data DATA            # writes examples/tiny_torch.pt beside this file
    simharness evaluate --data DATA --model examples/tiny_torch.py:TinyTorch --split all
    simharness closedloop stress/cut_in --predictor examples/tiny_torch.py:TinyTorch --seeds 0-9
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from torch import nn

from simharness.scene import Forecast, Scene

STEPS = 5  # velocity steps of history the model reads
WEIGHTS = Path(__file__).with_name("tiny_torch.pt")


def inputs(history: Scene, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """-> features (M, 3 * STEPS) float32 (velocities in m/s in the target's frame, then their valid flags),
    rotation (M, 2, 2) from the target's frame to the world frame, current velocity (M, 2) m/s, target frame."""
    k = min(STEPS + 1, history.num_frames)
    xy = history.xy[targets, -k:].astype(np.float64)  # (M, k, 2) metres, world frame
    ok = history.valid[targets, -k:]
    vel = np.zeros((len(targets), STEPS, 2))
    vel_ok = np.zeros((len(targets), STEPS), bool)
    if k > 1:
        vel[:, -(k - 1):] = np.diff(xy, axis=1) / history.dt
        vel_ok[:, -(k - 1):] = ok[:, 1:] & ok[:, :-1]
    h = history.heading[targets, -1].astype(np.float64)
    c, s = np.cos(h), np.sin(h)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (M, 2, 2) target frame -> world
    local = np.einsum("mji,mtj->mti", rot, vel) * vel_ok[..., None]  # (M, STEPS, 2) rotated into the target's frame
    fallback = np.stack([history.speed[targets, -1], np.zeros(len(targets))], -1)  # speed along the heading
    v_now = np.where(vel_ok[:, -1:], local[:, -1], fallback)
    features = np.concatenate([local.reshape(len(targets), -1), vel_ok], -1).astype(np.float32)
    return features, rot, v_now


class TinyTorch(nn.Module):
    """Constant velocity plus an MLP's velocity correction; `predict` is the `Predictor` protocol."""

    name = "tiny-torch"

    def __init__(self, weights: str | Path | None = WEIGHTS) -> None:
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(3 * STEPS, 32), nn.Tanh(), nn.Linear(32, 2))
        nn.init.zeros_(self.mlp[-1].weight)  # untrained: constant velocity
        nn.init.zeros_(self.mlp[-1].bias)
        self.sigma_rate = nn.Parameter(torch.tensor(0.5))  # m of position sigma per second ahead (softplus)
        if weights is not None:
            if not Path(weights).is_file():
                raise FileNotFoundError(f"no weights at {weights}; train them first: "
                                        "python examples/tiny_torch.py --data DATA")
            self.load_state_dict(torch.load(weights, weights_only=True))
        self.eval()

    def velocity(self, features: torch.Tensor, v_now: torch.Tensor) -> torch.Tensor:
        """(M, 3 * STEPS), (M, 2) -> corrected velocity (M, 2) m/s, target frame."""
        return v_now + self.mlp(features)

    @torch.no_grad()
    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        """history: N agents x T frames (column -1 is now); targets (M,); horizon F frames of history.dt s
        -> Forecast: mean (M, F, 2) metres, world frame; sigma_rho (M, F, 3) (sigma_x, sigma_y in m, rho)."""
        targets = np.asarray(targets, np.int64)
        features, rot, v_now = inputs(history, targets)
        v = self.velocity(torch.from_numpy(features), torch.from_numpy(v_now).float()).double().numpy()
        v_world = np.einsum("mij,mj->mi", rot, v)  # (M, 2) m/s
        t = np.arange(1, horizon + 1) * history.dt  # (F,) seconds ahead
        mean = history.xy[targets, -1, None].astype(np.float64) + v_world[:, None] * t[None, :, None]
        sigma = 0.1 + float(nn.functional.softplus(self.sigma_rate)) * t  # (F,) metres
        sigma_rho = np.zeros((len(targets), horizon, 3), np.float32)
        sigma_rho[..., 0] = sigma_rho[..., 1] = sigma
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=history.dt,
                        sigma_rho=sigma_rho)


def training_windows(data: Path) -> dict[str, torch.Tensor]:
    """Every TraPHic-protocol window (3 s history, 5 s future at 5 Hz) of a data set, as tensors."""
    from simharness.io.parquet import Dataset
    from simharness.protocols import get_protocol, history_and_truth, windows

    protocol, ds = get_protocol("traphic"), Dataset(data)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("features", "rot", "v_now", "xy", "truth", "valid", "t")}
    for sid in ds.scene_ids:
        scene = ds.scene(sid)
        for now, rows in windows(scene, protocol):
            hist, truth, valid = history_and_truth(scene, now, protocol)
            features, rot, v_now = inputs(hist, rows)
            for k, v in zip(("features", "rot", "v_now", "xy", "truth", "valid"),
                            (features, rot, v_now, hist.xy[rows, -1], truth[rows], valid[rows]), strict=True):
                parts[k].append(v)
            t = np.arange(1, protocol.future + 1) * hist.dt  # (F,) seconds ahead
            parts["t"].append(np.broadcast_to(t, (len(rows), protocol.future)))
    if not parts["features"]:
        raise SystemExit(f"{data}: no complete 3 s + 5 s windows to train on")
    return {k: torch.from_numpy(np.concatenate(v).astype(np.float32)) for k, v in parts.items()}


def train(data: Path, out: Path = WEIGHTS, epochs: int = 200, seed: int = 0) -> TinyTorch:
    """Fit the correction (mean Euclidean error) and the sigma rate (Gaussian NLL) full-batch with Adam."""
    torch.manual_seed(seed)
    w = training_windows(data)
    model = TinyTorch(weights=None).train()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(epochs):
        v = torch.einsum("mij,mj->mi", w["rot"], model.velocity(w["features"], w["v_now"]))
        mean = w["xy"][:, None] + v[:, None] * w["t"][..., None]  # (M, F, 2)
        err = (mean - w["truth"]).norm(dim=-1)  # (M, F) metres
        sigma = 0.1 + nn.functional.softplus(model.sigma_rate) * w["t"]
        nll = err.detach() ** 2 / (2 * sigma**2) + 2 * torch.log(sigma)  # isotropic 2-D Gaussian, up to a constant
        loss = (err * w["valid"]).sum() / w["valid"].sum() + (nll * w["valid"]).sum() / w["valid"].sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
    torch.save(model.state_dict(), out)
    return model.eval()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="train the tiny torch predictor on a simharness data set")
    parser.add_argument("--data", type=Path, required=True, help="data set folder (simharness generate)")
    parser.add_argument("--out", type=Path, default=WEIGHTS, help=f"weights file (default {WEIGHTS})")
    parser.add_argument("--epochs", type=int, default=200, help="full-batch Adam steps (default 200)")
    args = parser.parse_args()
    train(args.data, args.out, args.epochs)
    print(f"-> {args.out}")
