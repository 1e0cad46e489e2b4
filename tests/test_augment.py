"""The left-right mirror of a training batch equals the batch built from the mirrored scene."""

import dataclasses

import numpy as np
import torch

from predictor.augment import mirror_batch, mirror_cells
from predictor.features import FeatureStore, WindowConfig
from tests._predictor_data import flow_scene

CFG = WindowConfig()
GRIDS = {"nbr": CFG.neighbour_grid, "hz": CFG.horizon_grid}


def _mirrored(scene):
    xy = scene.xy.copy()
    xy[..., 1] *= -1
    return dataclasses.replace(scene, xy=xy, heading=-scene.heading)


def test_mirror_batch_is_the_batch_of_the_mirrored_scene():
    scene = flow_scene(3, n=20)
    a = FeatureStore.build([scene], ["s"], CFG)
    b = FeatureStore.build([_mirrored(scene)], ["s"], CFG)
    idx = np.arange(len(a))
    assert len(a) == len(b) > 50
    ta, tb = a.batch(idx).tensors(), b.batch(idx).tensors()
    flip = torch.ones(len(idx), dtype=torch.bool)
    got = mirror_batch(ta, flip, GRIDS)
    for key in ("hist", "nbr", "hz", "fut"):
        assert torch.allclose(got[key], tb[key], atol=1e-4), key
    # cells agree except where an agent sits on a cell boundary (none here) and keep -1 where empty
    assert torch.equal(got["nbr_cell"], tb["nbr_cell"]) and torch.equal(got["hz_cell"], tb["hz_cell"])
    assert (got["nbr_cell"] >= 0).sum() > 100


def test_mirror_only_flagged_samples_and_twice_is_identity():
    a = FeatureStore.build([flow_scene(4)], ["s"], CFG)
    t = a.batch(np.arange(40)).tensors()
    flip = torch.arange(40) % 2 == 0
    once = mirror_batch(t, flip, GRIDS)
    assert torch.equal(once["hist"][~flip], t["hist"][~flip]) and not torch.equal(once["hist"][flip], t["hist"][flip])
    twice = mirror_batch(once, flip, GRIDS)
    for key in ("hist", "nbr", "hz", "fut", "nbr_cell", "hz_cell"):
        assert torch.equal(twice[key], t[key]), key
    assert torch.equal(mirror_cells(torch.tensor([-1, 0, 4, 7]), 5), torch.tensor([-1, 4, 0, 7]))
