"""Replay backend on the real NGSIM (CommonRoad) and ETH/UCY samples: log playback is the recording, reactive
agents keep a gap to a braking ego, the ego is chosen by seed, pixels are refused, the closed loop runs on a
data set folder."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simharness.errors import UserError
from simharness.io import importers as im
from simharness.io.parquet import write_dataset
from simharness.metrics import collisions, safety
from simharness.scenario import load_scenario
from simharness.sim import make_simulator
from simharness.sim.base import EgoCommand, scene_from_frames
from simharness.sim.replay.recording import Recording, candidates, choose_ego
from simharness.sim.replay.routes import Routes

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="module")
def ngsim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("replay") / "ngsim"
    write_dataset(im.import_commonroad(sorted((DATA / "commonroad_ngsim").glob("*.xml"))), out, {"source": "test"})
    return out


def run(spec, seed: int, command=None, frames: int | None = None):  # noqa: ANN001, ANN201
    sim = make_simulator(spec)
    out = [sim.reset(seed)]
    for k in range((frames or spec.num_frames) - 1):
        out.append(sim.step(command(k, out[-1]) if command else None))
    return sim, scene_from_frames(out, spec.dt)


def test_log_playback_is_the_recording(ngsim: Path) -> None:
    spec = load_scenario(ngsim).with_overrides({"replay.mode": "log"})
    sim, scene = run(spec, 3)
    rec = Recording.load(ngsim)
    src = next(s for s in rec.scenes if str(s.meta.get("scene_id")) == sim.scene_id)
    first = int(np.argmax(src.valid[sim.ego]))
    stride = int(round(spec.dt / src.dt))
    for row, aid in enumerate(scene.agent_id):
        r = int(np.flatnonzero(src.agent_id == aid)[0])
        cols = first + stride * np.flatnonzero(scene.valid[row])
        assert src.valid[r, cols].all()
        np.testing.assert_allclose(scene.xy[row][scene.valid[row]], src.xy[r, cols], atol=1e-3)
    assert scene.agent_id[scene.ego] == src.agent_id[sim.ego]


def test_reactive_without_commands_is_log(ngsim: Path) -> None:
    log = load_scenario(ngsim).with_overrides({"replay.mode": "log"})
    _, a = run(log, 5)
    _, b = run(log.with_overrides({"replay.mode": "reactive"}), 5)
    assert a.equals(b)


def test_reactive_followers_brake_for_a_stopping_ego(ngsim: Path) -> None:
    """The ego brakes to a stop: under log replay someone runs into it; reactive agents keep off it."""
    base = load_scenario(ngsim).with_overrides({"duration": 6.0})
    hits = {}
    for mode in ("log", "reactive"):
        spec = base.with_overrides({"replay.mode": mode})
        count = 0
        for seed in range(6):
            _, scene = run(spec, seed, command=lambda k, f: EgoCommand(-6.0, 0.0))
            bh = collisions.box_heading(scene)
            contact = safety.ego_contact(scene.xy, bh, scene.length, scene.width, scene.valid, scene.ego)
            count += int(contact.any())
        hits[mode] = count
    assert hits["log"] >= 3  # the recording does not know the ego stopped
    assert hits["reactive"] <= hits["log"] - 3


def test_ego_choice_is_seeded_and_whole(ngsim: Path) -> None:
    rec = Recording.load(ngsim)
    frames = 31
    a = [choose_ego(rec, s, frames, 10.0) for s in range(20)]
    assert a == [choose_ego(rec, s, frames, 10.0) for s in range(20)]
    assert len(set(a)) > 5
    for i, row in a:
        va = rec.scenes[i].valid[row]
        first = int(np.argmax(va))
        assert va[first:first + frames].all()
        assert rec.scenes[i].agent_type[row] != 7
    # Stricter margins only remove candidates.
    s = rec.scenes[0]
    assert set(candidates(s, frames, 30.0)) <= set(candidates(s, frames, 10.0))
    with pytest.raises(UserError, match="edge_margin"):
        choose_ego(rec, 0, 10_000, 10.0)


def test_pedestrian_recording_replays_with_estimated_area(tmp_path: Path) -> None:
    out = tmp_path / "eth"
    write_dataset(im.import_eth_ucy([DATA / "eth_ucy" / "crowds_zara01.txt"]), out, {"source": "test"})
    spec = load_scenario(out)
    assert spec.ego.type == "pedestrian" and spec.replay.edge_margin == 2.0
    sim, scene = run(spec, 1)
    assert sim.road.drivable  # estimated from where the pedestrians walked
    inside = sim.road.on_road(scene.xy[scene.valid])
    assert inside.mean() > 0.95


def test_routes_read_back_their_points() -> None:
    xy = np.array([[[0, 0], [1, 0], [1, 0], [2, 1], [0, 0]]], np.float32)
    valid = np.array([[True, True, True, True, False]])
    r = Routes.from_tracks(xy, valid, np.zeros((1, 5), np.float32), 0.5)
    p, h = r.at(np.zeros(4, int), np.array([0.5, 1.0, 1.0 + np.sqrt(2), 1.0 + np.sqrt(2) + 1]))
    np.testing.assert_allclose(p, [[0.5, 0], [1, 0], [2, 1], [2 + np.sqrt(0.5), 1 + np.sqrt(0.5)]], atol=1e-6)
    np.testing.assert_allclose(h[2:], np.pi / 4, atol=1e-6)
    assert np.isnan(r.s_log[0, 4]) and r.v_log[0, 0] == pytest.approx(2.0)


def test_pixels_refused_in_one_line(tmp_path: Path) -> None:
    out = tmp_path / "traf"
    write_dataset(im.import_traf([DATA / "traf" / "TRAF11_gt.txt"]), out, {"source": "test"})
    r = subprocess.run([sys.executable, "-m", "simharness", "closedloop", str(out), "--predictor", "const-vel",
                        "--seeds", "0", "--out", str(tmp_path / "cl")], capture_output=True, text=True)
    assert r.returncode == 2
    assert "replay.pixel_scale" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    toml = tmp_path / "traf.toml"
    # A front-view video's boxes overlap a lot: a short episode and no edge margin leave agents to choose from.
    toml.write_text('backend = "replay"\ndata = "traf"\nduration = 1.0\nrecord_hz = 5.0\nstep_length = 0.2\n'
                    '[ego]\nenabled = true\n[replay]\npixel_scale = 0.05\nedge_margin = 0.0\n')
    sim, scene = run(load_scenario(toml), 0, frames=5)
    assert scene.units == "m" and sim.road.drivable


def test_closedloop_on_a_data_set_folder_oracle_is_exact(ngsim: Path, tmp_path: Path) -> None:
    toml = tmp_path / "ngsim_log.toml"
    toml.write_text(f'backend = "replay"\ndata = "{ngsim}"\nduration = 4.0\nrecord_hz = 5.0\nstep_length = 0.2\n'
                    '[road]\nspeed_limit = 18.0\n[ego]\nenabled = true\n[replay]\nmode = "log"\n')
    out = tmp_path / "cl"
    r = subprocess.run([sys.executable, "-m", "simharness", "closedloop", str(toml), "--predictor", "oracle",
                        "--seeds", "0-1", "--workers", "1", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    scores = json.loads((out / "scores.json").read_text())
    assert scores["online_ade"]["mean"] < 0.01
    assert all(e["at_fault_collided"] == 0 for e in scores["per_episode"])
