"""The compiled separating-axis test of two boxes against `metrics.collisions.boxes_overlap`."""

from __future__ import annotations

import numpy as np

from simharness.metrics.collisions import boxes_overlap
from simharness.metrics.separating_axis import may_overlap, overlap


def test_overlap_matches_boxes_overlap():
    """Random pairs, many of them touching or nearly so (rounded positions, right angles, equal sizes)."""
    rng = np.random.default_rng(8)
    p = 20000
    a, b = np.round(rng.uniform(-4, 4, (p, 2)), 1), np.round(rng.uniform(-4, 4, (p, 2)), 1)
    ha = rng.choice([0.0, np.pi / 2, np.pi, -np.pi / 2, 0.3], p) + rng.normal(0, 0.2, p) * (rng.random(p) < 0.5)
    hb = rng.choice([0.0, np.pi / 2, 0.3], p) + rng.normal(0, 0.2, p) * (rng.random(p) < 0.5)
    la, wa = rng.choice([0.5, 2.0, 4.5], p), rng.choice([0.5, 1.0, 1.8], p)
    lb, wb = rng.choice([0.5, 2.0, 4.5], p), rng.choice([0.5, 1.0, 1.8], p)
    ref = boxes_overlap(a, ha, la, wa, b, hb, lb, wb)
    ca, sa, cb, sb = np.cos(ha), np.sin(ha), np.cos(hb), np.sin(hb)
    got = np.array([overlap(a[i, 0], a[i, 1], ca[i], sa[i], la[i], wa[i], b[i, 0], b[i, 1], cb[i], sb[i], lb[i],
                            wb[i]) for i in range(p)])
    assert np.array_equal(got, ref) and 0.1 < ref.mean() < 0.9


def test_may_overlap_never_rules_out_an_overlap():
    rng = np.random.default_rng(2)
    p = 20000
    rel = rng.uniform(-8, 8, (p, 2))
    ha, la, wa = rng.uniform(-np.pi, np.pi, p), rng.uniform(0.4, 12, p), rng.uniform(0.4, 2.6, p)
    hb, lb, wb = 0.3, 4.5, 1.8
    hit = boxes_overlap(rel, ha, la, wa, np.zeros((p, 2)), np.full(p, hb), np.full(p, lb), np.full(p, wb))
    ca, sa, cb, sb = np.cos(ha), np.sin(ha), np.cos(hb), np.sin(hb)
    may = np.array([may_overlap(rel[i, 0], rel[i, 1], ca[i], sa[i], la[i], wa[i], cb, sb, lb, wb) for i in range(p)])
    assert hit.any() and (~may).any() and not np.any(hit & ~may)
