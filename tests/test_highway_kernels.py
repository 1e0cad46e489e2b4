"""The compiled pair searches of the highway backend against plain numpy (n, n) tables on random inputs.

The references are the table formulations the kernels replaced; results must match bit for bit, ties going to
the lowest row as `np.argmin` does, with every ego reaction (who sees the ego).
"""

from __future__ import annotations

import numpy as np
import pytest

from simharness.sim import highway_dynamics as dyn
from simharness.sim.highway_crossing import crossing_clear
from simharness.sim.highway_leaders import band_leaders, leaders
from simharness.sim.highway_room import lateral_room


def scene(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """n agents on 60 m of road, positions and speeds rounded so that equal gaps and speeds (ties) occur."""
    x = np.round(rng.uniform(0, 60, n), 1)
    y = np.round(rng.uniform(-5, 5, n), 1)
    hx, hy = rng.choice([0.3, 1.0, 2.25, 6.0], n), rng.choice([0.3, 0.45, 0.9, 1.25], n)
    vx = rng.choice([0.0, -0.0, 4.0, 8.0, 12.5], n) + np.round(rng.uniform(0, 1, n), 1) * (rng.random(n) < 0.5)
    lo = y - hy + np.minimum(rng.normal(0, 1, n), 0.0) * (rng.random(n) < 0.3)
    hi = y + hy + np.maximum(rng.normal(0, 1, n), 0.0) * (rng.random(n) < 0.3)
    is_ego = np.zeros(n, bool)
    is_ego[rng.integers(n)] = rng.random() < 0.8
    return dict(x=x, y=y, hx=hx, hy=hy, vx=vx, lo=lo, hi=hi, is_ego=is_ego, s0=rng.uniform(0.5, 3, n),
                v0=rng.uniform(1, 2, n), b=rng.uniform(1, 4, n), cross_dir=rng.choice([-1.0, 1.0], n))


def sees(a: dict[str, np.ndarray], ignore: bool) -> np.ndarray:
    """(n, n) whom row i takes into account: everyone but, when ignore, the ego for background rows."""
    n = a["x"].size
    out = np.ones((n, n), bool)
    if ignore:
        out[np.ix_(~a["is_ego"], a["is_ego"])] = False
    return out


def tables(a: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    dx = a["x"][None, :] - a["x"][:, None]
    dy = a["y"][None, :] - a["y"][:, None]
    return (dx, dy, np.abs(dx) - (a["hx"][:, None] + a["hx"][None, :]),
            np.abs(dy) - (a["hy"][:, None] + a["hy"][None, :]))


def masked_argmin(values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.where(mask, values, np.inf)
    j = np.argmin(v, axis=-1)
    best = np.take_along_axis(v, j[..., None], -1)[..., 0]
    return np.where(best == np.inf, 0, j), best


@pytest.mark.parametrize("ignore", [False, True])
def test_leaders_match_the_table_search(ignore):
    rng = np.random.default_rng(1)
    for _ in range(40):
        a = scene(rng, int(rng.integers(1, 60)))
        dx, _, gap, lat_gap = tables(a)
        m = 0.15
        cand = a["lo"][None, :] < (a["y"] + a["hy"] + m)[:, None]
        cand &= a["hi"][None, :] > (a["y"] - a["hy"] - m)[:, None]
        cand &= gap > 0
        cand |= lat_gap < m
        cand &= (dx > 0) & sees(a, ignore)
        ref_j, ref_g = masked_argmin(np.maximum(gap, 0.01), cand)
        j, g = leaders(a["x"], a["y"], a["hx"], a["hy"], a["lo"], a["hi"], a["is_ego"], ignore, m)
        assert np.array_equal(j, ref_j) and np.array_equal(g, ref_g)


@pytest.mark.parametrize("ignore", [False, True])
def test_band_leaders_match_the_search_over_everyone_where_they_look(ignore):
    """Within the horizon, at the offsets asked for: the gaps and leader speeds of the plain search over all agents
    (ties to the lowest row), so the same offset scores; elsewhere free road."""
    rng = np.random.default_rng(3)
    horizon = 20.0
    for _ in range(40):
        a = scene(rng, int(rng.integers(2, 60)))
        n = a["x"].size
        rows = np.sort(rng.choice(n, int(rng.integers(1, n + 1)), replace=False))
        cand = np.round(rng.uniform(-5, 5, (rows.size, 9)), 1)
        want = rng.random(cand.shape) < 0.6
        dx, _, gap, _ = tables(a)
        ahead = (dx > 0) & sees(a, ignore)
        ov = (a["lo"][None, None] < (cand + a["hy"][rows, None] + 0.15)[..., None]) & \
             (a["hi"][None, None] > (cand - a["hy"][rows, None] - 0.15)[..., None]) & ahead[rows][:, None]
        j, ref_gap = masked_argmin(np.broadcast_to(np.maximum(gap[rows], 0.0)[:, None], ov.shape), ov)
        ref_v = np.where(np.isfinite(ref_gap), a["vx"][j], np.inf)
        g, v = band_leaders(rows, cand, want, a["x"], a["hx"], a["hy"], a["lo"], a["hi"], a["vx"], a["is_ego"],
                            ignore, 0.15, horizon)
        near = want & (ref_gap <= horizon)
        assert np.array_equal(g[near], ref_gap[near]) and np.array_equal(v[near], ref_v[near])
        assert np.all(np.isinf(g[~near])) and np.all(np.isinf(v[~near]))


@pytest.mark.parametrize("reaction", ["reactive", "ignore", "cut_in"])
def test_lateral_room_matches_the_side_window_tables(reaction):
    """Side window written out per pair (the follower's half standstill gap and half speed plus its closing speed,
    the follower being whichever is behind), then the nearest box beside on each side."""
    rng = np.random.default_rng(5)
    for _ in range(40):
        a = scene(rng, int(rng.integers(1, 50)))
        n = a["x"].size
        dx, dy, gap, lat_gap = tables(a)
        window = np.zeros((n, n), bool)
        for i in range(n):
            for j in range(n):
                f, lead = (j, i) if dx[i, j] < 0 else (i, j)  # f follows lead
                margin = 0.5 * a["s0"][f] + 0.5 * a["vx"][f] + max(a["vx"][f] - a["vx"][lead], 0.0)
                window[i, j] = i != j and gap[i, j] < margin
        ignore = reaction != "reactive" and a["is_ego"].any()
        if ignore:
            window &= sees(a, True)
        if reaction == "cut_in":
            window |= (~a["is_ego"])[:, None] & a["is_ego"][None, :] & (gap < 0.3)
        beside = window & (lat_gap >= -1e-9)
        _, ref_l = masked_argmin(lat_gap, beside & (dy > 0))
        _, ref_r = masked_argmin(lat_gap, beside & (dy < 0))
        left, right = lateral_room(a["x"], a["y"], a["hx"], a["hy"], a["vx"], a["s0"], a["is_ego"], ignore,
                                   0.3 if reaction == "cut_in" else -np.inf)
        assert np.array_equal(left, ref_l) and np.array_equal(right, ref_r)


@pytest.mark.parametrize("ignore", [False, True])
def test_crossing_clear_matches_the_table_test(ignore):
    rng = np.random.default_rng(7)
    for _ in range(40):
        a = scene(rng, int(rng.integers(1, 50)))
        n = a["x"].size
        crossing = rng.random(n) < 0.3
        crossing[a["is_ego"]] = False
        ped = np.flatnonzero(crossing)
        x, y, hx, hy = a["x"], a["y"], a["hx"], a["hy"]
        d = a["cross_dir"][ped]
        reach = d * (a["v0"][ped] * dyn.PED_CLAIM_S + 0.3)
        lo = np.minimum(y[ped], y[ped] + reach) - hy[ped]
        hi = np.maximum(y[ped], y[ped] + reach) + hy[ped]
        veh = (~crossing)[None, :] & sees(a, ignore)[ped]
        lat = ((y - hy)[None, :] < hi[:, None]) & ((y + hy)[None, :] > lo[:, None])
        near_p, far_p = (x[ped] - hx[ped])[:, None], (x[ped] + hx[ped])[:, None]
        level = ((x + hx)[None, :] > near_p - 0.3) & ((x - hx)[None, :] < far_p + 0.3)
        dist = near_p - (x + hx)[None, :]
        v = a["vx"][None, :]
        stop = v**2 / (1.5 * a["b"][None, :]) + 0.5 * a["s0"][None, :] + 0.5 * v
        blocked = (veh & lat & (level | ((dist > 0) & (dist < stop)))).any(axis=1)
        ref = ~(blocked & (lo < 4.0) & (hi > -4.0))
        got = crossing_clear(ped, x, y, hx, hy, a["vx"], a["v0"], a["s0"], a["b"], a["cross_dir"], crossing,
                             a["is_ego"], ignore, 4.0)
        assert np.array_equal(got, ref)
