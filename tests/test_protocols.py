"""Standard protocols: the eth-ucy windowing of Social-GAN and its published constant-velocity figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simharness.io.importers import import_eth_ucy
from simharness.metrics.displacement import ade, fde
from simharness.predictors import load_predictor
from simharness.protocols import PROTOCOLS, history_and_truth, prepare, windows
from tests.conftest import make_scene

ETH = Path(__file__).resolve().parents[2] / "shared" / "data" / "eth_ucy"


def score(scene, protocol, predictor):
    preds, truths, valids = [], [], []
    for now, rows in windows(scene, protocol):
        hist, truth, tv = history_and_truth(scene, now, protocol)
        preds.append(predictor.predict(hist, rows, protocol.future).mean)
        truths.append(truth[rows])
        valids.append(tv[rows])
    p, t, v = map(np.concatenate, (preds, truths, valids))
    return ade(p, t, v), fde(p, t, v), len(p)


@pytest.mark.parametrize("name, published", [("biwi_hotel", (0.32, 0.61)), ("crowds_zara01", (0.43, 0.95))])
def test_const_vel_reproduces_published_eth_ucy(name, published):
    protocol = PROTOCOLS["eth-ucy"]
    scene = prepare(import_eth_ucy([ETH / f"{name}.txt"])[0], protocol)
    a, f, n = score(scene, protocol, load_predictor("const-vel"))
    assert n > 1000
    assert a == pytest.approx(published[0], abs=0.02) and f == pytest.approx(published[1], abs=0.02)


def test_eth_ucy_windowing_skips_gaps_and_lone_agents():
    protocol = PROTOCOLS["eth-ucy"]
    assert (protocol.history, protocol.future, protocol.hz, protocol.stride) == (8, 12, 2.5, 1)
    scene = make_scene(num_agents=3, num_frames=30, dt=0.4)
    valid = np.ones((3, 30), bool)
    valid[:, 10] = False  # a frame nobody was annotated in: skipped, not a gap
    valid[2, :] = False
    valid[2, 20:30] = True  # a third agent, never 20 frames long
    scene = scene.replace(valid=valid)
    compact = prepare(scene, protocol)
    assert compact.num_frames == 29 and compact.meta["empty_frames_skipped"] == 1
    found = list(windows(compact, protocol))
    assert len(found) == 29 - 20 + 1 and all(rows.tolist() == [0, 1] for _, rows in found)
    # One agent alone is not scored (Social-GAN keeps sequences with more than one pedestrian).
    lone = compact.replace(valid=compact.valid & (np.arange(3) == 0)[:, None])
    assert list(windows(lone, protocol)) == []
    # Without prepare the empty frame breaks every window through it.
    assert len(list(windows(scene, protocol))) < len(found)


def test_evaluate_cli_eth_ucy(tmp_path):
    import json
    import subprocess
    import sys

    data, out = tmp_path / "hotel", tmp_path / "eval"
    for cmd in (["import", "eth-ucy", str(ETH / "biwi_hotel.txt"), "--out", str(data)],
                ["evaluate", "--data", str(data), "--model", "const-vel", "--protocol", "eth-ucy", "--split", "all",
                 "--out", str(out)]):
        r = subprocess.run([sys.executable, "-m", "simharness", *cmd], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["ade"] == pytest.approx(0.32, abs=0.02) and metrics["fde"] == pytest.approx(0.61, abs=0.02)
    assert metrics["samples"] == 1053
