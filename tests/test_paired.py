"""Paired differences over common seeds: matching, the stratified bootstrap CI, the verdicts."""

import math

import numpy as np

from simharness.closedloop.paired import paired_difference, paired_values, stratified_ci, verdict


def test_paired_values_match_on_seed_and_drop_missing():
    a = [{"seed": 3, "x": 1.0}, {"seed": 1, "x": 0.0}, {"seed": 2, "x": math.nan}, {"seed": 5, "x": 1.0}]
    b = [{"seed": 1, "x": 1.0}, {"seed": 2, "x": 0.0}, {"seed": 3, "x": 0.0}, {"seed": 4, "x": 1.0}]
    seeds, va, vb = paired_values(a, b, "x")
    assert seeds.tolist() == [1, 3]  # 2 is nan in a, 4 and 5 ran for one ego only
    assert va.tolist() == [0.0, 1.0] and vb.tolist() == [1.0, 0.0]


def test_stratified_ci_weighs_scenarios_equally_and_resamples_within_them():
    # no spread inside either stratum: a stratified bootstrap has none to resample, however unequal the sizes
    ci = stratified_ci([np.zeros(40), np.ones(10)])
    assert ci["mean"] == 0.5 and ci["lo"] == 0.5 and ci["hi"] == 0.5 and ci["half_width"] == 0.0
    assert ci["n"] == 50 and ci["strata"] == 2


def test_ci_half_width_matches_the_normal_approximation():
    rng = np.random.default_rng(1)
    d = rng.choice([-1.0, 0.0, 0.0, 0.0, 1.0], size=400)  # at-fault differences: mostly ties
    ci = stratified_ci([d], resamples=8000)
    expected = 1.96 * d.std() / math.sqrt(d.size)
    assert abs(ci["half_width"] - expected) < 0.1 * expected
    assert ci["lo"] < d.mean() < ci["hi"]
    # pooled over S equal strata the half-width shrinks by sqrt(S)
    pooled = stratified_ci([d[:100], d[100:200], d[200:300], d[300:]], resamples=8000)
    assert abs(pooled["half_width"] - expected) < 0.15 * expected


def test_pairing_removes_the_shared_spread():
    rng = np.random.default_rng(0)
    shared = rng.normal(0, 1, 200)  # what both egos meet on a seed
    a, b = shared + 0.1 + rng.normal(0, 0.05, 200), shared + rng.normal(0, 0.05, 200)
    d = paired_difference([a], [b])
    assert d["lo"] > 0.0 and d["half_width"] < 0.02  # resolved, though each ego's own CI is +-0.14 wide
    assert abs(d["mean"] - (a - b).mean()) < 1e-12


def test_verdicts():
    neg = {"mean": -0.1, "lo": -0.15, "hi": -0.05, "n": 120}
    pos = {"mean": 0.1, "lo": 0.05, "hi": 0.15, "n": 120}
    zero = {"mean": 0.01, "lo": -0.02, "hi": 0.04, "n": 120}
    assert verdict("traphic", "const-vel", neg, "at_fault_collided") == "traphic is safer than const-vel"
    assert verdict("traphic", "const-vel", pos, "collided") == "const-vel is safer than traphic"
    assert verdict("traphic", "const-vel", pos, "composite") == "traphic scores higher than const-vel"
    assert verdict("traphic", "const-vel", neg, "composite") == "const-vel scores higher than traphic"
    assert verdict("traphic", "const-vel", zero, "at_fault_collided") == "no difference resolved at 120 episodes"
    assert verdict("a", "b", stratified_ci([]), "composite") == "no paired episodes"
