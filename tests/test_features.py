"""Windows, state space, neighbourhood / horizon selection and their grids, on hand-placed agents."""

import os

import numpy as np
import pytest

from predictor.features import (
    FEATURES,
    FeatureStore,
    WindowConfig,
    concentration,
    frame_concentration,
    frame_headings,
    scene_arrays,
    select_neighbours,
    to_local,
    to_world,
)
from predictor.windows_cache import cached_store, load_store
from simharness.errors import UserError
from simharness.scene import AgentType, Scene

CFG = WindowConfig()  # neighbourhood semi-axes (20, 6), horizon (15, 4.5), grids 13x5 and 7x5

# Target at the origin heading +x; the others hand-placed.
PLACED = {
    "target": (0, 0), "ahead": (10, 0), "behind": (-10, 0), "beside": (0, 4), "far_ahead": (25, 0),
    "far_side": (0, 7), "ahead_left": (14, 1), "ahead_wide": (10, 5),
}


def _select(theta: float = 0.0, shift=(0.0, 0.0), cfg: WindowConfig = CFG) -> dict[str, set[str]]:
    names = list(PLACED)
    xy = to_world(np.array([PLACED[n] for n in names], float), np.array(shift), np.array(theta))
    sel = select_neighbours(xy, np.full(len(names), theta), cfg)
    return {k: {names[r] for r in sel[k][0] if r >= 0} for k in ("nbr", "hz")}, sel


@pytest.mark.parametrize("theta", [0.0, np.pi / 2, -2.5])
def test_neighbourhood_and_horizon_membership(theta):
    got, _ = _select(theta, shift=(100.0, -40.0))
    assert got["nbr"] == {"ahead", "behind", "beside", "ahead_left", "ahead_wide"}
    assert got["hz"] == {"ahead", "ahead_left"}  # semi-ellipse: in front only; (10, 5) is outside 4.5 m


def test_nearest_kept_in_order_and_cells():
    got, sel = _select(cfg=WindowConfig(max_neighbours=2, max_horizon=1))
    names = list(PLACED)
    assert [names[r] for r in sel["nbr"][0]] == ["beside", "ahead"] or \
        [names[r] for r in sel["nbr"][0]] == ["beside", "behind"]
    assert [names[r] for r in sel["hz"][0]] == ["ahead"]
    _, sel = _select()
    row = list(sel["nbr"][0]).index(names.index("ahead"))
    # (10, 0) on a 13 x 5 grid over [-20, 20] x [-6, 6]: column floor(30 / 40 * 13) = 9, row floor(6 / 12 * 5) = 2
    assert sel["nbr_cell"][0][row] == 9 * 5 + 2
    hrow = list(sel["hz"][0]).index(names.index("ahead"))
    assert sel["hz_cell"][0][hrow] == int(10 / 15 * 7) * 5 + 2
    # an agent alone has no neighbours
    alone = select_neighbours(np.zeros((1, 2)), np.zeros(1), CFG)
    assert (alone["nbr"] == -1).all() and (alone["hz_cell"] == -1).all()


def test_concentration_counts_box_ahead():
    xy = np.array([[0, 0], [5, 0], [5, 1.4], [12, 0], [-3, 0], [5, 2]], float)
    c = concentration(xy, np.zeros(6), (10.0, 3.0))
    assert c[0] == 2  # (5, 0) and (5, 1.4); not beyond 10 m, not behind, not 2 m aside


def _scene(theta: float = 0.0, shift=(0.0, 0.0), scale: float = 1.0, units: str = "m") -> Scene:
    """Agents on curved paths with mixed types, one stationary with its own heading."""
    rng = np.random.default_rng(3)
    n, t, dt = 12, 60, 0.2
    time = np.arange(t) * dt
    v = rng.uniform(1, 9, n)
    w = rng.uniform(-0.1, 0.1, n)
    head0 = rng.uniform(-0.3, 0.3, n)
    head = head0[:, None] + w[:, None] * time
    xy = np.cumsum(np.stack([np.cos(head), np.sin(head)], -1) * v[:, None, None] * dt, 1)
    xy += np.stack([rng.uniform(0, 40, n), rng.uniform(-5, 5, n)], -1)[:, None]
    xy[0] = [20.0, 1.0]  # stationary
    head[0] = 0.7
    valid = np.ones((n, t), bool)
    valid[3, :10] = False
    valid[4, 45:] = False
    xy = to_world(xy, np.array(shift), np.array(theta))
    return Scene(xy=xy * scale, heading=head + theta, speed=np.repeat(v[:, None], t, 1), valid=valid,
                 agent_id=[f"a{i}" for i in range(n)], agent_type=[AgentType(i % 8) for i in range(n)],
                 length=np.full(n, 4.0) * scale, width=np.full(n, 1.8) * scale, dt=dt,
                 meta={"units": units, "units_per_m": scale} if units != "m" else {})


def test_features_invariant_to_rigid_motion():
    a = FeatureStore.build([_scene()], ["s"], CFG)
    b = FeatureStore.build([_scene(theta=1.1, shift=(-300.0, 55.0))], ["s"], CFG)
    assert len(a) == len(b) > 50
    idx = np.arange(len(a))
    ba, bb = a.batch(idx), b.batch(idx)
    for k in ("hist", "nbr", "hz", "fut"):
        np.testing.assert_allclose(getattr(ba, k), getattr(bb, k), atol=2e-3)
    for k in ("nbr_cell", "hz_cell", "fut_valid"):
        np.testing.assert_array_equal(getattr(ba, k), getattr(bb, k))
    assert ba.hist[:, -1, :2] == pytest.approx(0.0, abs=1e-5)  # the target's frame is centred on it
    assert (ba.nbr_cell >= 0).any() and (ba.hz_cell >= 0).any()


def test_stationary_heading_and_window_shapes():
    scene = _scene()
    h = frame_headings(scene, 1.0, CFG)
    assert h[0, 30] == pytest.approx(0.7)  # stationary: the scene's heading
    moving = np.arctan2(*(scene.xy[1, 30] - scene.xy[1, 25])[::-1])
    assert h[1, 30] == pytest.approx(moving, abs=1e-5)
    store = FeatureStore.build([scene], ["s"], CFG)
    b = store.batch(np.arange(4))
    assert b.hist.shape == (4, 15, len(FEATURES)) and b.fut.shape == (4, 25, 2)
    assert b.nbr.shape == (4, 12, 15, len(FEATURES)) and b.hz.shape == (4, 6, 15, len(FEATURES))
    # agent 4 leaves at frame 45: never a target with a window that needs later frames
    tgt_rows = (store.a["target"] // scene.num_frames)
    tgt_cols = store.a["target"] % scene.num_frames
    assert not ((tgt_rows == 4) & (tgt_cols + 25 >= 45)).any()


def test_pixel_units_scale_regions_and_never_pass_as_metres():
    m = FeatureStore.build([_scene()], ["s"], CFG)
    px = FeatureStore.build([_scene(scale=10.0, units="px")], ["s"], CFG)
    idx = np.arange(len(m))
    np.testing.assert_allclose(m.batch(idx).nbr, px.batch(idx).nbr, atol=2e-3)
    bare = _scene(scale=10.0, units="px")
    bare = bare.replace(meta={"units": "px"})
    with pytest.raises(UserError, match="units_per_m"):
        FeatureStore.build([bare], ["s"], CFG)


def test_store_cache_round_trip(tmp_path):
    calls = []

    def scenes_fn():
        calls.append(1)
        return [_scene()], ["s"]

    a = cached_store(tmp_path, "key", CFG, scenes_fn, progress=False)
    b = cached_store(tmp_path, "key", CFG, scenes_fn, progress=False)
    assert len(calls) == 1 and len(list(tmp_path.glob("*.npz"))) == 1
    for k in a.a:
        np.testing.assert_array_equal(a.a[k], b.a[k])
    assert (a.H, a.F, a.step) == (b.H, b.F, b.step) == (15, 25, 1)


def test_downsample_and_rate_checks():
    assert WindowConfig(downsample=2).frames(0.1) == (15, 25)
    assert WindowConfig().step(0.1) == 2
    with pytest.raises(UserError, match="whole multiple"):
        WindowConfig().step(0.3)
    p = to_local(np.array([[1.0, 2.0]]), np.zeros(2), np.array(0.4))
    np.testing.assert_allclose(to_world(p, np.zeros(2), np.array(0.4)), [[1.0, 2.0]], atol=1e-12)


def test_concentration_of_all_frames_at_once_equals_frame_by_frame():
    scene = _scene()
    arr = scene_arrays(scene, CFG)
    for t in range(scene.num_frames):
        rows = np.flatnonzero(scene.valid[:, t])
        np.testing.assert_array_equal(arr["conc"][rows, t],
                                      concentration(arr["xy"][rows, t], arr["heading"][rows, t], CFG.concentration_box))
    cols = np.arange(0, scene.num_frames, 3)
    small = frame_concentration(arr["xy"], arr["heading"], scene.valid, cols, CFG.concentration_box, max_pairs=200)
    np.testing.assert_array_equal(small[:, cols], arr["conc"][:, cols])  # many small chunks, same counts
    assert arr["conc"].max() >= 1 and not small[:, 1].any()


def test_cache_is_compact_and_never_trusted_when_stale_or_damaged(tmp_path):
    from predictor.windows_cache import save_store

    calls = []

    def scenes_fn():
        calls.append(1)
        return [_scene(), _scene(theta=0.5)], ["s", "t"]

    built = cached_store(tmp_path, "data-a", CFG, scenes_fn, progress=False)
    (path,) = tmp_path.glob("windows-*.npz")
    assert path.stat().st_size < sum(v.nbytes for v in built.a.values()) / 2  # compact on disk (16x on real data)
    again = cached_store(tmp_path, "data-a", CFG, scenes_fn, progress=False)
    assert len(calls) == 1
    idx = np.arange(len(built))
    for k in ("hist", "nbr", "hz", "fut", "nbr_cell", "hz_cell", "fut_valid"):
        np.testing.assert_array_equal(getattr(built.batch(idx), k), getattr(again.batch(idx), k))
    # other data or other windows: another key, a new build
    cached_store(tmp_path, "data-b", CFG, scenes_fn, progress=False)
    cached_store(tmp_path, "data-a", WindowConfig(max_neighbours=4), scenes_fn, progress=False)
    assert len(calls) == 3 and len(list(tmp_path.glob("windows-*.npz"))) == 3
    # a damaged file is rebuilt, silently and correctly
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    rebuilt = cached_store(tmp_path, "data-a", CFG, scenes_fn, progress=False)
    assert len(calls) == 4
    np.testing.assert_array_equal(rebuilt.batch(idx).nbr, built.batch(idx).nbr)
    # a readable file whose index points outside its data is refused with one clear line
    built.a["target"] = built.a["target"].astype(np.int64) + len(built.a["valid"])
    save_store(built, tmp_path / "bad.npz")
    with pytest.raises(UserError, match="damaged windows cache"):
        load_store(tmp_path / "bad.npz")
    with pytest.raises(UserError, match="unreadable windows cache"):
        load_store(tmp_path / "missing.npz")
    # files unused for a month go when a new one is written; those in use stay
    os.utime(path, (0, 0))
    cached_store(tmp_path, "data-c", CFG, scenes_fn, progress=False)
    assert not path.exists() and len(list(tmp_path.glob("windows-*.npz"))) == 3
