"""Forecast perturbations: degrade any predictor's forecasts in controlled ways (`PerturbedPredictor`).

A `Perturbation` names how much of each error to inject; `perturb` applies it to one forecast (pure,
seeded by the Generator it is given, vectorised over agents and steps); `PerturbedPredictor` wraps a
Predictor and applies it to every forecast of an episode (it keeps only its Generator and, for
latency, the forecasts it issued). Every error is measured where it lands: the loop's online ADE of
the perturbed forecasts is what `simharness sensitivity` plots the closed-loop figures against.

The errors, each a no-op at its default:
- noise (m): a position error per agent and forecast, N(0, noise^2) per axis at the last forecast step,
  growing linearly from 0 with the lead time (a velocity-like error: forecasts drift off smoothly); drawn
  from (seed, frame, agent id) alone, so that the exact oracle's branches, which serve their egos the same
  degraded forecasts as the live loop (`Degrader` copies), draw the same errors;
- latency (frames): the planner gets the forecast made `latency` frames ago, re-timed to now (agents
  that appeared since are missing from it);
- speed (x): each agent's displacement from its position now scaled (< 1 under-, > 1 over-estimated speed);
- heading (degrees): each displacement rotated about the agent's position now (+ counter-clockwise);
- drop (agent type): agents of that type left out of the forecast altogether;
- sigma (x): the forecast's position sigmas scaled (forecasts without sigmas are left as they are).
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.scene import AgentType, Forecast, Predictor, Scene

KEYS = ("noise", "latency", "speed", "heading", "drop", "sigma")


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """How much of each error to inject (see the module docstring); the defaults inject none."""

    noise: float = 0.0  # m: per-axis std of the position error at the last forecast step
    latency: int = 0  # frames the forecast is late
    speed: float = 1.0  # x: displacement scale
    heading: float = 0.0  # degrees: displacement rotation
    drop: str = ""  # agent type label left out of forecasts ("" none)
    sigma: float = 1.0  # x: sigma scale

    @property
    def is_identity(self) -> bool:
        return self == Perturbation()

    def label(self) -> str:
        """"noise=1" style: only the keys that differ from the defaults ("none" when none do)."""
        parts = [f"{k}={getattr(self, k):g}" if not isinstance(getattr(self, k), str) else f"{k}={getattr(self, k)}"
                 for k in KEYS if getattr(self, k) != getattr(Perturbation(), k)]
        return ",".join(parts) or "none"

    @classmethod
    def from_items(cls, items: dict[str, Any], where: str = "--perturb") -> Perturbation:
        """Validated from {key: value} (values as numbers or strings); UserError naming the key."""
        out: dict[str, Any] = {}
        for k, v in items.items():
            if k not in KEYS:
                raise UserError(f"{where}: unknown perturbation {k!r}; expected one of {', '.join(KEYS)}")
            if k == "drop":
                try:
                    out[k] = AgentType.parse(str(v)).label if str(v) else ""
                except UserError:
                    raise UserError(f"{where}: drop={v}: unknown agent type") from None
                continue
            try:
                x = float(v)
            except ValueError:
                raise UserError(f"{where}: {k}={v}: expected a number") from None
            if k == "latency":
                if x < 0 or x != int(x):
                    raise UserError(f"{where}: latency={v}: expected a whole number of frames >= 0")
                out[k] = int(x)
            elif k in ("noise", "speed", "sigma") and (x < 0 or not math.isfinite(x)):
                raise UserError(f"{where}: {k}={v}: expected a number >= 0")
            else:
                out[k] = x
        return cls(**out)


def parse_grid(texts: list[str]) -> list[Perturbation]:
    """`--perturb` values ("noise=0,0.5,1", "latency=0,2") -> the grid (cartesian product), in order."""
    axes: list[tuple[str, list[str]]] = []
    for text in texts:
        key, sep, values = text.partition("=")
        if not sep or not values.strip():
            raise UserError(f"--perturb {text!r}: expected KEY=V1,V2,... (keys: {', '.join(KEYS)})")
        axes.append((key.strip(), [v.strip() for v in values.split(",") if v.strip()]))
    grid: list[dict[str, str]] = [{}]
    for key, values in axes:
        grid = [{**g, key: v} for g in grid for v in values]
    return [Perturbation.from_items(g, f"--perturb {g}") for g in grid]


def unit_normals(seed: int, frame: int, agent_id: np.ndarray) -> np.ndarray:
    """(M, 2) standard normal draws fixed by (seed, frame, agent id) alone (splitmix64 hashes, Box-Muller)."""
    keys = np.array([zlib.crc32(str(a).encode()) for a in agent_id], np.uint64)
    base = _mix(np.array([int(seed) & 0xFFFFFFFF], np.uint64) * np.uint64(0x9E3779B97F4A7C15)
                + np.uint64(int(frame) & 0xFFFFFFFF))
    u = [(_mix(base ^ _mix(keys * np.uint64(2) + np.uint64(c))) >> np.uint64(11)).astype(np.float64) * 2.0**-53
         for c in (0, 1)]  # two uniforms in [0, 1) per agent
    r, t = np.sqrt(-2.0 * np.log1p(-u[0])), 2.0 * math.pi * u[1]
    return np.stack([r * np.cos(t), r * np.sin(t)], -1)


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser on uint64 arrays (wrapping arithmetic)."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def perturb(forecast: Forecast, now_xy: np.ndarray, agent_type: np.ndarray, p: Perturbation,
            unit_noise: np.ndarray | None = None) -> Forecast:
    """One forecast degraded by `p` (all but latency, which needs the past: see `PerturbedPredictor`).

    forecast: M agents x F steps; now_xy (M, 2) m: each agent's position now; agent_type (M,) codes;
    unit_noise (M, 2): standard normal draws that `p.noise` scales (`unit_normals`; needed when p.noise).
    Returns a new Forecast (M' <= M agents).
    """
    mean = forecast.mean.astype(np.float64)  # (M, F, 2)
    now = np.asarray(now_xy, np.float64)[:, None]  # (M, 1, 2)
    disp = (mean - now) * p.speed
    if p.heading:
        c, s = math.cos(math.radians(p.heading)), math.sin(math.radians(p.heading))
        disp = np.stack([c * disp[..., 0] - s * disp[..., 1], s * disp[..., 0] + c * disp[..., 1]], -1)
    mean = now + disp
    m, f = mean.shape[:2]
    if p.noise:
        grow = (np.arange(f) + 1.0) / f  # (F,): 0 now .. 1 at the last step
        mean = mean + p.noise * unit_noise[:, None] * grow[None, :, None]
    sigma_rho = forecast.sigma_rho
    if sigma_rho is not None and p.sigma != 1.0:
        sigma_rho = np.concatenate([sigma_rho[..., :2] * p.sigma, sigma_rho[..., 2:]], -1)
    keep = np.ones(m, bool)
    if p.drop:
        keep = np.asarray(agent_type) != int(AgentType.parse(p.drop))
    return Forecast(agent_id=forecast.agent_id[keep], mean=mean[keep].astype(np.float32), dt=forecast.dt,
                    sigma_rho=None if sigma_rho is None else sigma_rho[keep].astype(np.float32))


def retime(forecast: Forecast, late: int, horizon: int) -> Forecast:
    """A forecast made `late` frames ago as seen now: its first `late` steps dropped, the end extended
    at its last velocity back to `horizon` steps. mean (M, F, 2) -> (M, horizon, 2)."""
    mean = forecast.mean[:, late:]
    if mean.shape[1] == 0:  # older than its horizon: hold the last position
        mean = forecast.mean[:, -1:]
    last = forecast.mean[:, -1] - (forecast.mean[:, -2] if forecast.horizon > 1 else forecast.mean[:, -1])
    extra = horizon - mean.shape[1]
    if extra > 0:
        mean = np.concatenate([mean, mean[:, -1:] + last[:, None] * (np.arange(extra) + 1.0)[None, :, None]], 1)
    sigma = forecast.sigma_rho
    if sigma is not None:
        sigma = sigma[:, min(late, forecast.horizon - 1):]
        sigma = np.concatenate([sigma, np.repeat(sigma[:, -1:], max(horizon - sigma.shape[1], 0), 1)], 1)[:, :horizon]
    return Forecast(agent_id=forecast.agent_id, mean=mean[:, :horizon].astype(np.float32), dt=forecast.dt,
                    sigma_rho=sigma)


class Degrader:
    """What `PerturbedPredictor` does to each forecast, with its state (the past forecasts latency needs):
    copied into the exact oracle's branches, it serves their egos what the live planner is served."""

    def __init__(self, p: Perturbation, seed: int = 0) -> None:
        self.p, self.seed = p, int(seed)
        self._past: list[tuple[int, Forecast]] = []  # (frame made, forecast) while latency needs them

    def degrade(self, forecast: Forecast, now_xy: np.ndarray, agent_type: np.ndarray, now: int,
                horizon: int) -> Forecast:
        """A forecast made at frame `now` (now_xy (M, 2), agent_type (M,) of its agents), degraded."""
        noise = unit_normals(self.seed, now, forecast.agent_id) if self.p.noise else None
        out = perturb(forecast, now_xy, agent_type, self.p, unit_noise=noise)
        if self.p.latency <= 0:
            return out
        self._past = [(k, f) for k, f in self._past if k >= now - self.p.latency - horizon] + [(now, out)]
        due = [(k, f) for k, f in self._past if k <= now - self.p.latency]
        made, stale = due[-1] if due else self._past[0]  # the latest made long enough ago (or the oldest kept)
        return retime(stale, now - made, horizon)


class PerturbedPredictor:
    """Any Predictor with its forecasts degraded by a `Perturbation` (see the module docstring).

    inner: the predictor; p: the errors; seed: seeds the noise (same seed, frame and agent -> same error).
    """

    def __init__(self, inner: Predictor, p: Perturbation, seed: int = 0) -> None:
        self.inner = inner
        self.p = p
        self.degrader = Degrader(p, seed)

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        """As the inner predictor's, degraded: (M' <= M, horizon, 2)."""
        targets = np.asarray(targets, int)
        return self.degrade(self.inner.predict(history, targets, horizon), history.xy[targets, -1],
                            history.agent_type[targets], history.frame0 + history.num_frames - 1, horizon)

    def degrade(self, forecast: Forecast, now_xy: np.ndarray, agent_type: np.ndarray, now: int,
                horizon: int) -> Forecast:
        """A forecast made at frame `now` (now_xy (M, 2), agent_type (M,) of its agents), degraded."""
        return self.degrader.degrade(forecast, now_xy, agent_type, now, horizon)
