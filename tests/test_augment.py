"""The left-right mirror of a training batch equals the batch built from the mirrored scene; the scaled batch, the
batch of the scaled scene (regions scaled alike); and a training run with both learns."""

import dataclasses

import numpy as np
import torch

from predictor.augment import mirror_batch, mirror_cells, random_scales, scale_batch
from predictor.features import FeatureStore, WindowConfig
from predictor.train import train
from tests._predictor_data import flow_scene, write_flow_dataset

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


def _scaled(scene, s: float):
    return dataclasses.replace(scene, xy=scene.xy * s, speed=scene.speed * s, length=scene.length * s,
                               width=scene.width * s)


def test_scale_batch_is_the_batch_of_the_scaled_scene():
    scene, s = flow_scene(5, n=20), 1.7
    big = dataclasses.replace(CFG, neighbour_axes=tuple(a * s for a in CFG.neighbour_axes),
                              horizon_axes=tuple(a * s for a in CFG.horizon_axes),
                              concentration_box=tuple(a * s for a in CFG.concentration_box),
                              min_motion=CFG.min_motion * s)
    a = FeatureStore.build([scene], ["s"], CFG)
    b = FeatureStore.build([_scaled(scene, s)], ["s"], big)
    idx = np.arange(len(a))
    ta, tb = a.batch(idx).tensors(), b.batch(idx).tensors()
    got = scale_batch(ta, torch.full((len(idx),), s))
    for key in ("hist", "nbr", "hz", "fut"):
        assert torch.allclose(got[key], tb[key], atol=1e-3, rtol=1e-4), key
    assert torch.equal(got["nbr_cell"], tb["nbr_cell"]) and (got["nbr_cell"] >= 0).sum() > 100
    assert torch.equal(ta["hist"], a.batch(idx).tensors()["hist"])  # the input batch is left as it was


def test_random_scales_stay_in_range_and_are_one_without_jitter():
    rng = np.random.default_rng(0)
    s = random_scales(rng, 5000, 0.5)
    assert s.min() >= 1 / 1.5 - 1e-6 and s.max() <= 1.5 + 1e-6 and abs(float(s.log().mean())) < 0.02
    assert torch.equal(random_scales(rng, 7, 0.0), torch.ones(7))


def test_training_with_scale_jitter_learns(tmp_path):
    data = write_flow_dataset(tmp_path / "data", scenes=4)
    res = train(data, "traphic", tmp_path / "run", epochs=3, warmup_epochs=3, batch_size=64, max_samples=512,
                threads=1, progress=False, augment=True, scale_jitter=0.3, select="mse", cache_dir=tmp_path / "c")
    val = [h["mse"] for h in res["val_history"]]
    assert val[-1] < 0.5 * val[0] and res["config"]["train"]["scale_jitter"] == 0.3
