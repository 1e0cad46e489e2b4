"""Training-time augmentation: the left-right mirror of a batch, the one symmetry of lane-less traffic, and a
change of scale, the one thing a video's unknown pixel scale (or a scene's walking speed) changes.

Every sample is in its target's frame (x ahead, y to its left), so mirroring is y -> -y on every lateral
quantity of every agent (y, vy, rel_vy), on the ground-truth future, and on the lateral grid cell of each
neighbour and horizon agent. A model trained on both halves cannot learn a side preference that one
training video happens to have (traffic keeping left, a kerb on the right): it sees each scene and its
mirror image, twice the situations for the same data.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from predictor.features import FEATURES

_LATERAL = [FEATURES.index(f) for f in ("y", "vy", "rel_vy")]
# Every feature in metres or metres per second; the rest (concentration counts, type, presence) has no unit.
_METRIC = [FEATURES.index(f) for f in ("x", "y", "vx", "vy", "length", "width", "rel_vx", "rel_vy", "distance")]


def mirror_cells(cell: torch.Tensor, lateral_cells: int) -> torch.Tensor:
    """Grid cells (..., K) int64, index along * lateral_cells + lateral, -1 none -> the mirrored cells."""
    lat = cell % lateral_cells
    return torch.where(cell >= 0, cell - lat + (lateral_cells - 1 - lat), cell)


def mirror_batch(b: dict[str, torch.Tensor], flip: torch.Tensor, grids: dict[str, tuple[int, int]]
                 ) -> dict[str, torch.Tensor]:
    """Mirror the samples where flip (B,) bool is True -> a new batch dict (the input is not changed).

    b: `Batch.tensors()` (hist (B, H, D), nbr (B, Kn, H, D), hz (B, Kh, H, D), nbr_cell / hz_cell (B, K),
    fut (B, F, 2), fut_valid (B, F)); grids: {"nbr": neighbour_grid, "hz": horizon_grid} (along, lateral) cells.
    """
    sign = torch.ones(b["hist"].shape[-1], dtype=b["hist"].dtype)
    sign[_LATERAL] = -1.0
    per = torch.where(flip[:, None], sign, torch.ones_like(sign))  # (B, D)
    out = dict(b)
    out["hist"] = b["hist"] * per[:, None]
    for key in ("nbr", "hz"):
        out[key] = b[key] * per[:, None, None]
        out[key + "_cell"] = torch.where(flip[:, None], mirror_cells(b[key + "_cell"], grids[key][1]),
                                         b[key + "_cell"])
    fsign = torch.where(flip, -1.0, 1.0).to(b["fut"].dtype)
    out["fut"] = torch.stack([b["fut"][..., 0], b["fut"][..., 1] * fsign[:, None]], -1)
    return out


def scale_batch(b: dict[str, torch.Tensor], scale: torch.Tensor) -> dict[str, torch.Tensor]:
    """Scale every sample's lengths by scale (B,) > 0 -> a new batch dict (the input is not changed).

    The result is the batch of the scene scaled by `scale` about any point, with the interaction regions and the
    concentration box scaled alike (so the same agents in the same grid cells, the same counts): the scene as
    seen at another pixel scale, or walked at another speed. Positions, velocities, relative velocities,
    distances and sizes of every agent, and the ground-truth future, are multiplied; cells and counts are kept.
    """
    per = torch.ones(len(scale), b["hist"].shape[-1], dtype=b["hist"].dtype)
    per[:, _METRIC] = scale.to(per.dtype)[:, None]
    out = dict(b)
    out["hist"] = b["hist"] * per[:, None]
    for key in ("nbr", "hz"):
        out[key] = b[key] * per[:, None, None]
    out["fut"] = b["fut"] * scale.to(b["fut"].dtype)[:, None, None]
    return out


def random_scales(rng: np.random.Generator, n: int, jitter: float) -> torch.Tensor:
    """n scale factors (n,) float32, log-uniform in [1 / (1 + jitter), 1 + jitter] (1 where jitter is 0)."""
    r = math.log1p(jitter)
    return torch.from_numpy(np.exp(rng.uniform(-r, r, n)).astype(np.float32))
