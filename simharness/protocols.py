"""Evaluation protocols: which windows of a scene are scored and at what rate.

`windows(scene, protocol)` yields (now column, target rows) for every scored window; the history
handed to a predictor is the `history` frames up to now taken every `step` recorded frames, the
ground truth the `future` frames after it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np

from simharness.errors import UserError
from simharness.scene import Scene


@dataclasses.dataclass(frozen=True)
class EvalProtocol:
    """name; history / future frames at the protocol rate; hz: protocol rate (the step in recorded frames is
    round(1 / (hz dt))); downsample: if set, that step in recorded frames (the paper's down-sampling for dense
    data), overriding hz; stride: protocol steps between scored "now"s; target: the selection rule,
    "full-window" = agents present at every protocol frame of history and future."""

    name: str
    history: int
    future: int
    hz: float | None = 5.0
    downsample: int | None = None
    stride: int = 5
    target: str = "full-window"
    # Social-GAN's windowing (eth-ucy): frames where nobody is annotated are skipped, not kept as gaps
    # (see `prepare`), and a window is scored only with at least `min_targets` full-window agents.
    skip_empty_frames: bool = False
    min_targets: int = 1

    def step(self, dt: float) -> int:
        if self.downsample is not None:
            return int(self.downsample)
        ratio = 1.0 / (float(self.hz) * dt)
        if ratio < 0.999 or abs(ratio - round(ratio)) > 1e-3:
            raise UserError(f"protocol {self.name!r} samples at {self.hz:g} Hz; the data is recorded at "
                            f"{1 / dt:g} Hz, not a whole multiple")
        return int(round(ratio))


# The TraPHic paper: 3 s history, 5 s future; 5 Hz windows (its dense data down-sampled by 2).
PROTOCOLS: dict[str, EvalProtocol] = {
    "traphic": EvalProtocol("traphic", history=15, future=25, hz=5.0, stride=5),
    # ETH/UCY as in Social-GAN (agrimgupta92/sgan, sgan/data/trajectories.py): 8 observed + 12 predicted
    # frames at 0.4 s, every window (skip 1) over the annotated frames with gaps ignored, pedestrians
    # present in all 20 frames, windows with more than one such pedestrian (its min_ped=1, strict).
    "eth-ucy": EvalProtocol("eth-ucy", history=8, future=12, hz=2.5, stride=1, skip_empty_frames=True,
                            min_targets=2),
    # ApolloScape trajectory as its challenge scores it: 2 Hz, 3 observed + 3 predicted frames (the data comes
    # as chunks of about 6 frames, so each chunk gives about one window), agents present in all 6.
    "apolloscape": EvalProtocol("apolloscape", history=3, future=3, hz=2.0, stride=1),
}


def get_protocol(name: str) -> EvalProtocol:
    if name not in PROTOCOLS:
        raise UserError(f"unknown protocol {name!r}; expected one of {', '.join(PROTOCOLS)}")
    return PROTOCOLS[name]


def prepare(scene: Scene, protocol: EvalProtocol) -> Scene:
    """The scene as the protocol windows it: with `skip_empty_frames`, columns where no agent is valid are
    dropped (Social-GAN counts only annotated frames, so a window may span a recording gap). Call it once
    per scene before `windows` and `history_and_truth`."""
    if not protocol.skip_empty_frames:
        return scene
    keep = np.flatnonzero(scene.valid.any(axis=0))
    if keep.size == scene.num_frames:
        return scene
    return scene.replace(xy=scene.xy[:, keep], heading=scene.heading[:, keep], speed=scene.speed[:, keep],
                         valid=scene.valid[:, keep], extra={k: v[:, keep] for k, v in scene.extra.items()},
                         meta={**scene.meta, "empty_frames_skipped": int(scene.num_frames - keep.size)})


def windows(scene: Scene, protocol: EvalProtocol) -> Iterator[tuple[int, np.ndarray]]:
    """(now column, target rows (M,)) of every scored window of `scene`, in time order."""
    if protocol.target != "full-window":
        raise UserError(f"protocol {protocol.name!r}: unknown target rule {protocol.target!r}")
    step = protocol.step(scene.dt)
    offs = np.arange(-(protocol.history - 1), protocol.future + 1) * step
    nows = np.arange((protocol.history - 1) * step, scene.num_frames - protocol.future * step,
                     max(1, protocol.stride) * step)
    if nows.size == 0:
        return
    ok = scene.valid[:, nows[:, None] + offs[None, :]].all(-1)  # (N, W)
    for w, now in enumerate(nows):
        rows = np.flatnonzero(ok[:, w])
        if rows.size and rows.size >= protocol.min_targets:
            yield int(now), rows


def history_and_truth(scene: Scene, now: int, protocol: EvalProtocol) -> tuple[Scene, np.ndarray, np.ndarray]:
    """(history Scene at the protocol rate ending at now, truth (N, F, 2), truth valid (N, F)) for all agents."""
    step = protocol.step(scene.dt)
    cols = now - np.arange(protocol.history - 1, -1, -1) * step
    c = np.maximum(cols, 0)
    hist = scene.replace(xy=scene.xy[:, c], heading=scene.heading[:, c], speed=scene.speed[:, c],
                         valid=scene.valid[:, c] & (cols >= 0)[None], dt=scene.dt * step, frame0=0,
                         extra={k: v[:, c] for k, v in scene.extra.items()})
    fut = now + np.arange(1, protocol.future + 1) * step
    f = np.minimum(fut, scene.num_frames - 1)
    return hist, scene.xy[:, f], scene.valid[:, f] & (fut < scene.num_frames)[None]


def window_seconds(protocol: EvalProtocol) -> dict[str, float]:
    """The protocol's windows in seconds, as a predictor's training windows take them:
    {"history_s", "future_s", "hz"} (eth-ucy: 3.2 s of 8 frames + 4.8 s of 12 frames at 2.5 Hz)."""
    if protocol.downsample is not None or not protocol.hz:
        raise UserError(f"protocol {protocol.name!r} is defined in recorded frames (downsample "
                        f"{protocol.downsample}), not seconds; train with a window config instead")
    return {"history_s": protocol.history / protocol.hz, "future_s": protocol.future / protocol.hz,
            "hz": float(protocol.hz)}
