"""Do re-annotated copies of the training scenes let the gated blend of lags carry over to another recording?
A model-free check: the residual models' blend (`predictor.models.gaussian.LagBlend`) fitted by least squares.

    python bench/reannotate_blend.py        # after bench/real_goals.py has prepared data/real14 (a few seconds)

For every window of the held-out recording, the forecast is constant velocity (last step) plus sum_l w_l (mean
displacement over the last l steps - the last step) * k at future step k, l = 2 .. 5, with w_l = a_l + b_l * j and j
the jitter pooled over every agent present over the window's history (`predictor.models.gaussian.pooled_jitter`'s
measure). a and b are fitted on the training recording alone, then with its copies (`predictor.reannotate`: smoothed
over 0.5 s, and 0.1 m of white noise), and the forecast scored (mean Euclidean ADE) on the held-out one: the ETH/UCY
whole-scene folds (train on one scene, test the other) and the two TRAF video groups both ways.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from real_goals import TRAF_A, TRAF_B  # noqa: E402  (the same two groups of videos)

from predictor.reannotate import RECORDED, reannotated  # noqa: E402
from simharness.io.parquet import Dataset  # noqa: E402
from simharness.metrics.displacement import ade  # noqa: E402
from simharness.protocols import get_protocol, prepare, windows  # noqa: E402

LAGS = 5


def jitter(h: np.ndarray) -> float:
    """Pooled jitter of tracks h (N, H, 2): minus the lag-1 autocorrelation of their second differences."""
    d2 = h[:, 2:] - 2 * h[:, 1:-1] + h[:, :-2]
    return float(-(d2[:, 1:] * d2[:, :-1]).sum() / ((d2 ** 2).sum() + 1e-9))


def tracks(scene, protocol: str) -> tuple[np.ndarray, np.ndarray]:
    """(windows (M, H + F, 2) of every scored target, pooled jitter (M,)) of one scene, its own units."""
    p = get_protocol(protocol)
    s = prepare(scene, p)
    step, out, pj = p.step(s.dt), [], []
    for now, rows in windows(s, p):
        cols = now + step * np.arange(-(p.history - 1), p.future + 1)
        hist = cols[:p.history]
        out.append(s.xy[rows][:, cols].astype(np.float64))
        pj.append(np.full(len(rows), jitter(s.xy[s.valid[:, hist].all(1)][:, hist].astype(np.float64))))
    return np.concatenate(out), np.concatenate(pj)


def design(tr: np.ndarray, pj: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X (M, F * 2, 2 (LAGS - 1)), y (M, F * 2): the future minus constant velocity, cv (M, F, 2))."""
    hist, fut = tr[:, :h], tr[:, h:]
    k = np.arange(1, fut.shape[1] + 1)[None, :, None]
    last = hist[:, -1] - hist[:, -2]
    lags = [(hist[:, -1] - hist[:, -1 - lag]) / lag - last for lag in range(2, LAGS + 1)]
    cols = lags + [d * pj[:, None] for d in lags]
    cv = hist[:, -1:] + k * last[:, None]
    x = np.stack([(k * c[:, None]).reshape(len(tr), -1) for c in cols], -1)
    return x, (fut - cv).reshape(len(tr), -1), cv


def fit(x: np.ndarray, y: np.ndarray, lam: float = 1e-3) -> np.ndarray:
    a, b = np.einsum("nfp,nfq->pq", x, x), np.einsum("nfp,nf->p", x, y)
    return np.linalg.solve(a + lam * np.trace(a) / len(a) * np.eye(len(a)), b)


def fold(train: list, test: list, protocol: str, window) -> tuple[float, float, float]:
    """ADE of (constant velocity, the blend fitted without copies, with copies) on `test`."""
    h = get_protocol(protocol).history
    te = [tracks(s, protocol) for _, s in test]
    tr_te, pj_te = np.concatenate([t[0] for t in te]), np.concatenate([t[1] for t in te])
    x_te, _, cv = design(tr_te, pj_te, h)
    fut = tr_te[:, h:]
    ok = np.ones(fut.shape[:2], bool)
    scores = [ade(cv, fut, ok)]
    for levels in ((), RECORDED):
        scenes = [s for _, s in train] + [reannotated(s, sid, lv, window.scale_for(s)) for sid, s in train
                                          for lv in levels]
        tr = [tracks(s, protocol) for s in scenes]
        x, y, _ = design(np.concatenate([t[0] for t in tr]), np.concatenate([t[1] for t in tr]), h)
        pred = cv + (x_te @ fit(x, y)).reshape(cv.shape)
        scores.append(ade(pred, fut, ok))
    return tuple(scores)


def main() -> int:
    from predictor.train import protocol_window

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT / "data" / "real14")
    args = ap.parse_args()
    print("| fold | test windows | constant velocity | blend, no copies | blend, with copies |")
    print("|---|---|---|---|---|")
    eth = Dataset(args.data / "eth-not-biwi_hotel")  # holds hotel whole and zara01's train/val parts
    zara = Dataset(args.data / "eth-not-crowds_zara01")  # holds zara01 whole
    hotel, zara01 = eth.scene("biwi_hotel"), zara.scene("crowds_zara01")
    w = protocol_window("eth-ucy")
    for name, train, test in (("ETH/UCY whole, test biwi_hotel", [("crowds_zara01", zara01)], [("h", hotel)]),
                              ("ETH/UCY whole, test crowds_zara01", [("biwi_hotel", hotel)], [("z", zara01)])):
        n = len(tracks(test[0][1], "eth-ucy")[0])
        print(f"| {name} | {n} | " + " | ".join(f"{v:.3f}" for v in fold(train, test, "eth-ucy", w)) + " |")
    traf = Dataset(args.data / "traf")
    group = {g: [(i, traf.scene(i)) for i in traf.scene_ids if i.removesuffix("_gt") in names]
             for g, names in (("A", TRAF_A), ("B", TRAF_B))}
    w = protocol_window("traphic")
    for a, b in (("A", "B"), ("B", "A")):
        n = sum(len(tracks(s, "traphic")[0]) for _, s in group[b])
        print(f"| TRAF {a}->{b} (px) | {n} | " + " | ".join(f"{v:.2f}" for v in fold(group[a], group[b], "traphic", w))
              + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
