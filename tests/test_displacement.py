"""Displacement metrics and the bivariate Gaussian NLL on hand-computed cases."""

import math

import numpy as np
import pytest
import torch
from scipy.stats import multivariate_normal

from predictor.losses import gaussian_nll, mse
from simharness.metrics import displacement as dm

# Two samples, three frames. Sample 0 errors 3, 4, 5 (x offsets); sample 1 errors 0, 5, (invalid).
TRUTH = np.zeros((2, 3, 2))
PRED = np.array([[[3, 0], [0, 4], [3, 4]], [[0, 0], [3, 4], [100, 100]]], float)
VALID = np.array([[True, True, True], [True, True, False]])


def test_ade_fde_both_ways():
    assert dm.ade(PRED, TRUTH, VALID) == pytest.approx((3 + 4 + 5 + 0 + 5) / 5)
    assert dm.fde(PRED, TRUTH, VALID) == pytest.approx((5 + 5) / 2)  # sample 1 ends at its last valid frame
    assert dm.ade_rmse(PRED, TRUTH, VALID) == pytest.approx(math.sqrt((9 + 16 + 25 + 0 + 25) / 5))
    assert dm.fde_rmse(PRED, TRUTH, VALID) == pytest.approx(5.0)
    s = dm.summary(PRED, TRUTH, VALID)
    assert s["samples"] == 2 and s["ade"] == pytest.approx(3.4)


def test_rmse_per_step_and_second():
    np.testing.assert_allclose(dm.rmse_per_step(PRED, TRUTH, VALID), [math.sqrt(4.5), math.sqrt(20.5), 5.0])
    # dt 0.5 s, 4 frames: seconds 1 and 2 are frames 1 and 3.
    pred = np.zeros((1, 4, 2))
    pred[0, :, 0] = [1, 2, 3, 4]
    np.testing.assert_allclose(dm.rmse_per_second(pred, np.zeros((1, 4, 2)), np.ones((1, 4), bool), 0.5), [2, 4])


def test_miss_rate_and_min_of_k():
    assert dm.miss_rate(PRED, TRUTH, VALID, 2.0) == 1.0
    assert dm.miss_rate(PRED, TRUTH, VALID, 5.0) == 0.0
    modes = np.stack([PRED, PRED * 0.1, PRED * 10], 1)  # (M, K=3, F, 2): the second mode is best
    ade_k, fde_k = dm.min_ade_fde(modes, TRUTH, VALID)
    assert ade_k == pytest.approx(((0.3 + 0.4 + 0.5) / 3 + (0 + 0.5) / 2) / 2)
    assert fde_k == pytest.approx(0.5)


def test_breakdowns():
    out = dm.by_group(PRED, TRUTH, VALID, np.array([0, 7]), {0: "car", 7: "pedestrian"})
    assert out["car"]["ade"] == pytest.approx(4.0) and out["pedestrian"]["fde"] == pytest.approx(5.0)
    bins, names = dm.density_bins(np.array([0, 5, 12, 40]))
    assert bins.tolist() == [0, 1, 2, 3] and names[3] == ">=20" and names[1] == "5-9"


def test_nll_hand_values():
    one = np.ones((1, 1))
    mean, truth = np.zeros((1, 1, 2)), np.zeros((1, 1, 2))
    unit = np.array([[[1.0, 1.0, 0.0]]])
    assert dm.bivariate_nll(mean, unit, truth, one) == pytest.approx(math.log(2 * math.pi))
    truth[0, 0] = [1, 0]
    assert dm.bivariate_nll(mean, unit, truth, one) == pytest.approx(math.log(2 * math.pi) + 0.5)
    wide = np.array([[[2.0, 1.0, 0.0]]])  # sigma_x = 2 is a standard deviation: z = 1/4
    assert dm.bivariate_nll(mean, wide, truth, one) == pytest.approx(math.log(2 * math.pi) + math.log(2) + 0.125)


def test_nll_matches_scipy_and_torch_loss():
    rng = np.random.default_rng(0)
    mean, truth = rng.normal(size=(5, 4, 2)), rng.normal(size=(5, 4, 2))
    sr = np.concatenate([rng.uniform(0.3, 2, (5, 4, 2)), rng.uniform(-0.9, 0.9, (5, 4, 1))], -1)
    valid = rng.random((5, 4)) > 0.3
    ref = []
    for i, j in zip(*np.nonzero(valid), strict=True):
        sx, sy, r = sr[i, j]
        cov = [[sx * sx, r * sx * sy], [r * sx * sy, sy * sy]]
        ref.append(-multivariate_normal(mean[i, j], cov).logpdf(truth[i, j]))
    assert dm.bivariate_nll(mean, sr, truth, valid) == pytest.approx(np.mean(ref), rel=1e-9)
    pred = torch.tensor(np.concatenate([mean, sr], -1))
    got = gaussian_nll(pred, torch.tensor(truth), torch.tensor(valid))
    assert float(got) == pytest.approx(np.mean(ref), rel=1e-6)
    sq = ((mean - truth) ** 2).sum(-1)[valid].mean()
    assert float(mse(pred, torch.tensor(truth), torch.tensor(valid))) == pytest.approx(sq)
