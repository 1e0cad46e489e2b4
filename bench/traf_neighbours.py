"""Is there a neighbour signal that transfers between TRAF videos? A model-free check, no network involved.

    python bench/traf_neighbours.py [--data data/real14/traf]   # the import bench/real_goals.py makes

For every `traphic`-protocol window of the two video groups of bench/real_goals.py, ridge regressions predict the
target's future minus constant velocity over its last 5 steps (the smoothed reference) from (a) its own history
(its last 5 displacements, its image position, its smoothed velocity) and (b) the same plus its neighbours' motion
at now (agents present now and 1 s before: the distance-weighted, the mean and the nearest one's velocity over the
last second, each relative to the target's, and two counts). Fitted on one group, scored (mean Euclidean ADE, px)
on the other. If (b) is not below (a), a linear read of the neighbours' motion carries nothing to unseen videos.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from real_goals import TRAF_B  # noqa: E402  (the same two groups of videos)

from simharness.io.parquet import Dataset  # noqa: E402
from simharness.metrics.displacement import ade  # noqa: E402
from simharness.protocols import get_protocol, windows  # noqa: E402

LAG = 5  # steps of the smoothed constant velocity (1 s at 5 Hz)
LAMBDA = 1e3  # ridge penalty on standardised features (fixed, not chosen on the test group)


def scene_rows(scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(own features (M, 2 LAG + 4), neighbour features (M, 8), future (M, F, 2) relative to now), image pixels,
    of every scored target of one scene."""
    p = get_protocol("traphic")
    step, xy, valid = p.step(scene.dt), scene.xy.astype(np.float64), scene.valid
    own, nbr, fut = [], [], []
    for now, rows in windows(scene, p):
        cols = now + step * np.arange(-(p.history - 1), p.future + 1)
        tr = xy[rows][:, cols]  # (M, H + F, 2)
        d = np.diff(tr[:, :p.history], axis=1)  # (M, H - 1, 2)
        cv = d[:, -LAG:].mean(1)
        back = now - LAG * step  # within the history (LAG < history), so never before the first frame
        present = valid[:, now] & valid[:, back]
        vel = (xy[:, now] - xy[:, back]) / LAG  # (N, 2) per step over the last second
        rel = xy[None, :, now] - tr[:, p.history - 1, None]  # (M, N, 2)
        dist = np.linalg.norm(rel, axis=-1)
        mask = present[None] & (np.arange(len(xy))[None] != rows[:, None])  # (M, N) neighbours, not the target
        w = np.exp(-dist / 100.0) * mask
        local = (w[..., None] * vel[None]).sum(1) / (w.sum(1, keepdims=True) + 1e-6)
        mean = (mask[..., None] * vel[None]).sum(1) / np.maximum(mask.sum(1, keepdims=True), 1)
        nearest = vel[np.where(mask, dist, np.inf).argmin(1)] * mask.any(1, keepdims=True)
        counts = np.stack([np.log1p((mask & (dist < 100)).sum(1)), np.log1p(mask.sum(1))], -1)
        # own: the last LAG displacements (the last one first of the final pair), position, then cv (last 2 columns)
        own.append(np.concatenate([d[:, -LAG:].reshape(len(rows), -1), tr[:, p.history - 1] / 1000, cv], 1))
        nbr.append(np.concatenate([local - cv, mean - cv, nearest - cv, counts], 1))
        fut.append(tr[:, p.history:] - tr[:, p.history - 1, None])
    if not own:
        return np.zeros((0, 2 * LAG + 4)), np.zeros((0, 8)), np.zeros((0, p.future, 2))
    return np.concatenate(own), np.concatenate(nbr), np.concatenate(fut)


def ridge(x: np.ndarray, y: np.ndarray, lam: float):
    """Standardised ridge regression -> predict(x) (the intercept unpenalised)."""
    mu, sd = x.mean(0), x.std(0) + 1e-9
    xs = (x - mu) / sd
    w = np.linalg.solve(xs.T @ xs + lam * np.eye(x.shape[1]), xs.T @ (y - y.mean(0)))
    return lambda z: ((z - mu) / sd) @ w + y.mean(0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT / "data" / "real14" / "traf")
    args = ap.parse_args()
    ds = Dataset(args.data)
    groups: dict[str, list] = {"A": [], "B": []}
    for sid in ds.scene_ids:
        groups["B" if sid.removesuffix("_gt") in TRAF_B else "A"].append(scene_rows(ds.scene(sid)))
    data = {g: [np.concatenate([r[i] for r in rs]) for i in range(3)] for g, rs in groups.items()}
    print("| fold | test windows | constant velocity | over the last 5 steps | ridge, own history | ridge, own + "
          "neighbours |\n|---|---|---|---|---|---|")
    for tr, te in (("A", "B"), ("B", "A")):
        (own, nbr, fut), (own2, nbr2, fut2) = data[tr], data[te]
        k = np.arange(1, fut.shape[1] + 1)[None, :, None]
        every = np.ones(fut2.shape[:2], bool)
        cv2 = own2[:, -2:][:, None] * k  # smoothed constant velocity (the features' last two columns)
        last = own2[:, 2 * LAG - 2:2 * LAG][:, None] * k  # the last displacement: plain constant velocity
        target = (fut - own[:, -2:][:, None] * k).reshape(len(fut), -1)
        cells = [ade(last, fut2, every), ade(cv2, fut2, every)]
        for x, x2 in ((own, own2), (np.hstack([own, nbr]), np.hstack([own2, nbr2]))):
            corrected = cv2.reshape(len(fut2), -1) + ridge(x, target, LAMBDA)(x2)
            cells.append(ade(corrected.reshape(fut2.shape), fut2, every))
        print(f"| {tr}->{te} | {len(fut2)} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
