"""A trained model behind the `Predictor` protocol: world-frame forecasts for many agents in one call."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from predictor.checkpoint import load_checkpoint
from predictor.features import FeatureStore, WindowConfig, to_world
from simharness.scene import Forecast, Scene

WEIGHTS = Path(__file__).parent / "weights"


class ModelPredictor:
    """Wraps a model trained by predictor.train; `predict` batches every target of the frame."""

    def __init__(self, model: Any, window: WindowConfig, name: str = "model", info: dict[str, Any] | None = None,
                 threads: int = 1):
        """threads: torch threads during `predict` (restored after). One by default: 100 agents take ~20 ms of one
        core, the result does not depend on the machine's load, and on a loaded machine two threads spin-wait
        for a busy core (measured 4x slower)."""
        self.model = model
        self.window = window
        self.name = name
        self.info = info or {}
        self.threads = int(threads)

    @staticmethod
    def from_files(weights: Path, config: Path) -> ModelPredictor:
        model, cfg = load_checkpoint(Path(weights), Path(config))
        return ModelPredictor(model, WindowConfig.from_dict(cfg["window"]), cfg["model"], cfg)

    @staticmethod
    def from_run(run: Path) -> ModelPredictor:
        """A run folder written by `simharness train` (model.pt + config.json)."""
        return ModelPredictor.from_files(Path(run) / "model.pt", Path(run) / "config.json")

    @staticmethod
    def shipped(name: str = "traphic") -> ModelPredictor:
        """The weights shipped in predictor/weights/NAME.pt + NAME.json."""
        return ModelPredictor.from_files(WEIGHTS / f"{name}.pt", WEIGHTS / f"{name}.json")

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        """history: last frames of all agents (column -1 is now, any rate that is a whole multiple of the
        model's); targets (M,) rows present at now; horizon: frames of history.dt. -> Forecast, world frame."""
        import torch

        targets = np.asarray(targets, np.int64)
        absent = targets[~history.valid[targets, -1]]
        if absent.size:
            raise ValueError(f"targets {history.agent_id[absent][:5].tolist()} are not present at the last frame")
        store = FeatureStore.build([history], ["history"], self.window, targets=[targets], require_future=False)
        batch = store.batch(np.arange(len(targets)))
        inputs = batch.tensors()
        caller_threads = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        try:
            with torch.inference_mode():  # no autograd records, and oneDNN's inference kernels for the LSTMs
                out = self.model(inputs).numpy().astype(np.float64)  # (M, F, 5) local, metres
                # Sampling models (Social-GAN) also give K futures (M, K, F, 2): Forecast.modes, for best-of-K scores.
                samples = self.model.sample(inputs).numpy().astype(np.float64) if hasattr(
                    self.model, "sample") else None
        finally:
            torch.set_num_threads(caller_threads)
        step, fm = store.step, out.shape[1]
        if horizon > fm * step:
            raise ValueError(f"{self.name} predicts {fm * step} frames of {history.dt:g} s, asked for {horizon}")
        # Model steps are `step` recorded frames long: interpolate to every recorded frame (now = zero offset).
        out = np.concatenate([np.zeros_like(out[:, :1]), out], 1)
        out[:, 0, 2:4] = out[:, 1, 2:4]  # sigma at "now" is only used as an interpolation end point
        pos = np.arange(1, horizon + 1) / step
        j0 = np.minimum(np.floor(pos).astype(int), fm - 1)
        w = (pos - j0)[None, :, None]
        out = out[:, j0] * (1 - w) + out[:, j0 + 1] * w
        scale = self.window.scale_for(history)
        origin, heading = batch.origin[:, None].astype(np.float64), batch.heading[:, None].astype(np.float64)
        mean = to_world(out[..., :2], origin, heading) * scale
        # Covariance rotated from the target frame to the world frame: R S R^T.
        sx, sy, rho = out[..., 2], out[..., 3], np.clip(out[..., 4], -0.9999, 0.9999)
        c, s = np.cos(heading), np.sin(heading)
        cxx, cyy, cxy = sx**2, sy**2, rho * sx * sy
        wxx = c * c * cxx - 2 * c * s * cxy + s * s * cyy
        wyy = s * s * cxx + 2 * c * s * cxy + c * c * cyy
        wxy = c * s * (cxx - cyy) + (c * c - s * s) * cxy
        wsx, wsy = np.sqrt(wxx), np.sqrt(wyy)
        sigma_rho = np.stack([wsx * scale, wsy * scale, wxy / (wsx * wsy)], -1)
        modes = None
        if samples is not None:
            samples = np.concatenate([np.zeros_like(samples[:, :, :1]), samples], 2)
            samples = samples[:, :, j0] * (1 - w[None]) + samples[:, :, j0 + 1] * w[None]
            modes = (to_world(samples, origin[:, None], heading[:, None]) * scale).astype(np.float32)
        gaussian = getattr(self.model, "gaussian", True)  # False: the model gives samples, not a density
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=history.dt,
                        sigma_rho=sigma_rho.astype(np.float32) if gaussian else None, modes=modes)
