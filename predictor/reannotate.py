"""Training recordings re-annotated at other noise levels: each training scene copied with white noise added to
every position, with drift (noise correlated along time, as a tracker's filter leaves it), or smoothed along time.

Why: annotation noise belongs to a recording (its camera, its tracker, its annotators), so a model trained on one
or two recordings sees one or two noise levels, and what the residual models' gate learns (smooth the jittery
tracks, keep or extrapolate the clean ones: `predictor.models.gaussian.LagBlend`) cannot carry over to a recording
annotated otherwise. Copies at other levels show the gate the same motion at several noise levels: a noisier copy
(`noisy`), a drifting one (`drifting`: filtered tracks wander slowly, so their speed sways by a few tenths of a
metre per second over a second or so, which the gate would otherwise read as real speed changes and extrapolate)
and a cleaner one (`smoothed`: a Gaussian-weighted local line along time over each track's own frames, future
included, as an offline annotation tool smooths). Validation and test scenes are never copied.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence

import numpy as np
from scipy.ndimage import correlate1d

from simharness.errors import UserError
from simharness.scene import Scene

VERSION = 1  # of the copies' making: part of their windows' cache key
# (kind, level): ("noise", std in metres), ("drift", std in metres) or ("smooth", kernel std in seconds).
Level = tuple[str, float]
KINDS = ("smooth", "noise", "drift")
# Drift's correlation time (s), drawn per copy log-uniform in this range: trackers filter over 0.2 s to a second.
DRIFT_S = (0.2, 1.0)

# The copies `simharness train` makes by default for a gated residual model on recorded data: one smoothed over 0.5 s,
# one with 0.1 m of noise (docs/results.md). None on simulator output (exact positions: the
# copies cost 1-7% there) nor for the paper's form (no gate to read the noise level: they cost up to 25%).
RECORDED: tuple[Level, ...] = (("smooth", 0.5), ("noise", 0.1))


def simulated(info: dict) -> bool:
    """Whether a data set's manifest `info` says a simulator wrote it (`simharness generate`): exact positions."""
    return info.get("source") == "simharness generate" or "backend" in info


def parse_levels(noise: Sequence[float] | None, smooth: Sequence[float] | None, by_default: bool = True,
                 drift: Sequence[float] | None = None) -> tuple[Level, ...]:
    """Noise and drift stds (metres) and smoothing kernel stds (seconds) -> levels, smoothing first, then noise,
    then drift. None: the default of that kind, `RECORDED` if by_default else none; 0 entries are dropped.
    UserError if a level is not a positive finite number below 100."""
    given = {"smooth": smooth, "noise": noise, "drift": drift}
    levels = [(kind, float(v)) for kind in KINDS
              for v in (given[kind] if given[kind] is not None else
                        [x for k, x in RECORDED if k == kind] if by_default else []) if v != 0]
    bad = [f"{k} {v:g}" for k, v in levels if not (np.isfinite(v) and 0 < v < 100)]
    if bad:
        raise UserError(f"bad re-annotation level(s) {', '.join(bad)}; expected metres of noise or drift or seconds "
                        "of smoothing, positive and below 100, e.g. --reannotate-noise 0.1 --reannotate-smooth 0.5")
    return tuple(levels)


def level_name(level: Level) -> str:
    """A level's tag in copied scene ids and run configs, e.g. "noise0.1m", "smooth0.5s"."""
    kind, v = level
    return f"{kind}{v:g}{'s' if kind == 'smooth' else 'm'}"


def noisy(scene: Scene, sigma_m: float, scale: float, seed: int) -> Scene:
    """The scene with white Gaussian noise of std sigma_m metres (scale: scene units per metre) added to every valid
    position, independently per agent, frame and axis."""
    noise = np.random.default_rng(seed).normal(0.0, sigma_m * scale, scene.xy.shape)
    return scene.replace(xy=np.where(scene.valid[..., None], scene.xy + noise, scene.xy).astype(np.float32))


def drifting(scene: Scene, sigma_m: float, scale: float, seed: int) -> Scene:
    """The scene with drift of std sigma_m metres (scale: scene units per metre) added to every valid position: white
    noise smoothed along time by a Gaussian of std tau seconds, tau drawn from the seed log-uniform in DRIFT_S (one
    tracker per recording), independently per agent and axis, rescaled to std sigma_m."""
    rng = np.random.default_rng(seed)
    tau = float(np.exp(rng.uniform(*np.log(DRIFT_S))))
    r = max(1, int(np.ceil(4 * tau / scene.dt)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) * scene.dt / tau) ** 2)
    k /= np.sqrt((k * k).sum())  # unit variance out for unit variance in
    white = rng.normal(0.0, 1.0, (scene.num_agents, scene.num_frames + 2 * r, 2))
    drift = correlate1d(white, k, axis=1, mode="constant")[:, r:r + scene.num_frames] * (sigma_m * scale)
    return scene.replace(xy=np.where(scene.valid[..., None], scene.xy + drift, scene.xy).astype(np.float32))


def smoothed(scene: Scene, sigma_s: float) -> Scene:
    """The scene with every track smoothed along time: at each valid frame, the value of a straight line fitted to
    the track's own valid frames under Gaussian weights of std sigma_s seconds (local linear regression). Inside a
    track that is the Gaussian-weighted mean; at its ends and gaps, the line keeps the track's trend where a
    plain mean would pull the end back, and a straight track at constant speed is unchanged."""
    r = max(1, int(np.ceil(4 * sigma_s / scene.dt)))
    tau = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (tau * scene.dt / sigma_s) ** 2)
    w = scene.valid.astype(np.float64)
    xy = np.where(scene.valid[..., None], scene.xy, 0.0).astype(np.float64)

    def corr(a: np.ndarray, weights: np.ndarray) -> np.ndarray:  # sum over tau of weights(tau) a(t + tau)
        return correlate1d(a, weights, axis=1, mode="constant")

    s0, s1, s2 = corr(w, k), corr(w, tau * k), corr(w, tau * tau * k)
    x0 = corr(xy, k)
    x1 = corr(xy, tau * k)
    det = s0 * s2 - s1 * s1
    ok = scene.valid & (det > 1e-9 * np.maximum(s0 * s2, 1e-300))  # one frame alone: no line, kept as it is
    fit = (s2[..., None] * x0 - s1[..., None] * x1) / np.where(ok, det, 1.0)[..., None]
    return scene.replace(xy=np.where(ok[..., None], fit, scene.xy).astype(np.float32))


def reannotated(scene: Scene, scene_id: str, level: Level, scale: float) -> Scene:
    """One copy of `scene` at `level`; the noise is seeded by the scene id and the level, so a copy is the same in
    every run (and its windows can be cached)."""
    kind, v = level
    if kind == "smooth":
        return smoothed(scene, v)
    seed = zlib.crc32(f"{scene_id}|{level_name(level)}".encode())
    return drifting(scene, v, scale, seed) if kind == "drift" else noisy(scene, v, scale, seed)


def copy_id(scene_id: str, level: Level) -> str:
    """The scene id of a copy, e.g. "crowds_zara01_train~noise0.1m"."""
    return f"{scene_id}~{level_name(level)}"
