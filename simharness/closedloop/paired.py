"""Paired comparisons of two egos run on the same seeds (common random numbers): the per-seed difference, its
mean with a 95% percentile-bootstrap CI, pooled over scenarios by stratified resampling, and a plain verdict.

On the same seed both egos meet the same traffic until they act differently, so most of the episode-to-episode
spread cancels in the per-seed difference: its CI is much narrower than the two unpaired CIs side by side.
Pooled over S scenarios, each scenario weighs the same (the pooled difference is the mean of the scenarios'
mean differences) and the bootstrap resamples seeds within each scenario, never across.

Pure functions of arrays (seeded); no simulator.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

RESAMPLES = 4000
LEVEL = 0.95
SAFETY_KEYS = ("at_fault_collided", "collided")  # lower is safer: the verdict says "safer"


def paired_values(a: Sequence[dict[str, Any]], b: Sequence[dict[str, Any]], key: str
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episodes' scores of two egos matched on seed: the seeds both ran (with a finite `key` in both).

    a, b: per-episode score dicts (each with "seed") -> seeds (E,) int, a's values (E,), b's values (E,) float.
    """
    def by_seed(eps: Sequence[dict[str, Any]]) -> dict[int, float]:
        out = {}
        for e in eps:
            v = e.get(key)
            if v is not None and math.isfinite(v):
                out[int(e["seed"])] = float(v)
        return out

    va, vb = by_seed(a), by_seed(b)
    seeds = np.array(sorted(va.keys() & vb.keys()), np.int64)
    return seeds, np.array([va[s] for s in seeds], np.float64), np.array([vb[s] for s in seeds], np.float64)


def stratified_ci(strata: Sequence[np.ndarray], resamples: int = RESAMPLES, level: float = LEVEL, seed: int = 0
                  ) -> dict[str, float | int]:
    """Mean over strata of each stratum's mean, with a percentile-bootstrap CI resampling within each stratum.

    strata: S arrays, stratum s (E_s,) float (e.g. per-seed differences on one scenario; empty ones are left
    out) -> {"mean", "lo", "hi", "half_width", "n" (episodes), "strata"}; nan where no stratum has a value.
    One stratum is the plain percentile bootstrap of its mean.
    """
    strata = [np.asarray(x, np.float64) for x in strata]
    strata = [x[np.isfinite(x)] for x in strata]
    strata = [x for x in strata if x.size]
    if not strata:
        return {"mean": math.nan, "lo": math.nan, "hi": math.nan, "half_width": math.nan, "n": 0, "strata": 0}
    rng = np.random.default_rng(seed)
    means = np.stack([x[rng.integers(0, x.size, (resamples, x.size))].mean(1) for x in strata])  # (S, R)
    pooled = means.mean(0)  # (R,)
    a = (1 - level) / 2
    # rounded: a mean of exact ties summed in another order must read 0, not -1e-17, for the verdict
    lo, hi = round(float(np.quantile(pooled, a)), 12), round(float(np.quantile(pooled, 1 - a)), 12)
    return {"mean": round(float(np.mean([x.mean() for x in strata])), 12), "lo": lo, "hi": hi,
            "half_width": round((hi - lo) / 2, 12),
            "n": int(sum(x.size for x in strata)), "strata": len(strata)}


def paired_difference(a: Sequence[np.ndarray], b: Sequence[np.ndarray], resamples: int = RESAMPLES,
                      level: float = LEVEL, seed: int = 0) -> dict[str, float | int]:
    """A minus B, paired: per stratum (scenario) s, a[s] and b[s] are (E_s,) values on the same seeds in the same
    order; -> `stratified_ci` of the differences a[s] - b[s] (pairs with a non-finite side dropped)."""
    return stratified_ci([np.asarray(x, np.float64) - np.asarray(y, np.float64) for x, y in zip(a, b, strict=True)],
                         resamples, level, seed)


def verdict(a: str, b: str, diff: dict[str, Any], key: str) -> str:
    """The plain reading of a paired difference A minus B of per-episode `key` with its CI.

    A CI wholly below 0 on a safety key (at_fault_collided, collided; lower is better) reads "A is safer than B",
    wholly above "B is safer than A"; on any other key (composite: higher is better) "A scores higher than B" or
    "B scores higher than A"; a CI that holds 0 reads "no difference resolved at N episodes".
    """
    n = int(diff.get("n") or 0)
    lo, hi = diff.get("lo"), diff.get("hi")
    if not n or lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return "no paired episodes"
    if lo <= 0 <= hi:
        return f"no difference resolved at {n} episodes"
    better, worse = (a, b) if (hi < 0) == (key in SAFETY_KEYS) else (b, a)
    return f"{better} is safer than {worse}" if key in SAFETY_KEYS else f"{better} scores higher than {worse}"
