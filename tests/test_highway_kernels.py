"""The compiled pair searches of the highway backend against plain numpy (n, n) tables on random inputs.

The references are the table formulations the kernels replaced; results must match bit for bit, ties going to
the lowest row as `np.argmin` does, with every ego reaction (who sees the ego).
"""

from __future__ import annotations

import numpy as np
import pytest

from simharness.sim.highway import dynamics as dyn
from simharness.sim.highway.crossing import crossing_clear
from simharness.sim.highway.decision import CUT_IN_BONUS, choose_offsets
from simharness.sim.highway.leaders import band_leaders, leaders
from simharness.sim.highway.room import lateral_room


def scene(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """n agents on 60 or 400 m of road (the scans along x stop early on the long one), positions and speeds
    rounded so that equal gaps and speeds (ties) occur."""
    x = np.round(rng.uniform(0, rng.choice([60.0, 400.0]), n), 1)
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
        j, g = leaders(np.argsort(a["x"]), a["x"], a["y"], a["hx"], a["hy"], a["lo"], a["hi"], a["is_ego"], ignore, m)
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
        g, v = band_leaders(np.argsort(a["x"]), rows, cand, want, a["x"], a["hx"], a["hy"], a["lo"], a["hi"], a["vx"],
                            a["is_ego"], ignore, 0.15, horizon)
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
        left, right = lateral_room(np.argsort(a["x"]), a["x"], a["y"], a["hx"], a["hy"], a["vx"], a["s0"], a["is_ego"],
                                   ignore, 0.3 if reaction == "cut_in" else -np.inf)
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


def offset_scores(gap, v_lead, v, v0, s0, headway, b, cand_y, y, kerb_bias, kerb_y):  # noqa: ANN001, ANN201
    """The (R, C) numpy formulation of the offset score."""
    free = gap > dyn.LOOKAHEAD
    hold = np.where(free, v0[:, None], v_lead + np.maximum(gap - s0[:, None], 0.0) / (headway[:, None] + 0.5))
    hold = np.minimum(hold, v0[:, None])
    closing = np.maximum(v[:, None] - np.where(free, v[:, None], v_lead), 0.0)
    unsafe = closing**2 > 2.0 * b[:, None] * np.maximum(gap - s0[:, None], 0.01)
    kerb = kerb_bias[:, None] * np.abs(cand_y - kerb_y) / max(abs(kerb_y) * 2, 1e-6)
    return np.where(unsafe, -np.inf, hold - dyn.LAT_COST * np.abs(cand_y - y[:, None]) - kerb)


@pytest.mark.parametrize("stay_allowed", [True, False])
def test_choose_offsets_matches_the_table_decision(stay_allowed):
    """Candidates, reachability, scores, the cut-in bonus, argmax (ties to the first offset) and the switch rule
    as (R, C) numpy tables; the leaders come from band_leaders (tested above)."""
    rng = np.random.default_rng(11)
    half_width, edge, min_gap = 5.25, 0.2, 0.3
    for _ in range(60):
        a = scene(rng, int(rng.integers(2, 50)))
        n = a["x"].size
        rows = np.sort(rng.choice(n, int(rng.integers(1, n + 1)), replace=False))
        grid = np.arange(-half_width, half_width + 1e-9, rng.choice([0.35, 1.0, 3.5]))
        y_target = np.round(a["y"] + rng.normal(0, 1, n), 1)
        room_l, room_r = rng.choice([0.1, 0.5, 2.0, np.inf], n), rng.choice([0.1, 0.5, 2.0, np.inf], n)
        v0, headway = a["v0"] * 8, rng.uniform(0.8, 2, n)
        margin = rng.uniform(0.1, 1.0, n)
        kerb_bias = rng.choice([0.0, 1.5], rows.size)
        cut_in = rng.random(rows.size) < 0.3
        ego_y, ego_hy = float(rng.uniform(-3, 3)), 0.9
        ignore = bool(rng.random() < 0.5)

        cand = np.empty((rows.size, grid.size + 2))
        cand[:, :-2], cand[:, -2], cand[:, -1] = grid, a["y"][rows], y_target[rows]
        inside = np.abs(cand) + a["hy"][rows, None] <= half_width - edge
        shift = cand - a["y"][rows, None]
        ok = inside & (shift <= room_l[rows, None] - min_gap) & (shift >= -(room_r[rows, None] - min_gap))
        ok[:, -2] = stay_allowed
        ok[:, -1] = inside[:, -1]
        order = np.argsort(a["x"])
        gap, v_lead = band_leaders(order, rows, cand, ok, a["x"], a["hx"], a["hy"], a["lo"], a["hi"], a["vx"],
                                   a["is_ego"], ignore, 0.5 * min_gap, dyn.LOOKAHEAD)
        scores = offset_scores(gap, v_lead, a["vx"][rows], v0[rows], a["s0"][rows], headway[rows], a["b"][rows],
                               cand, a["y"][rows], kerb_bias, half_width)
        scores += np.where(cut_in[:, None] & (np.abs(cand - ego_y) < a["hy"][rows, None] + ego_hy), CUT_IN_BONUS, 0.0)
        scores = np.where(ok, scores, -np.inf)
        best = np.argmax(scores, axis=1)
        top, plan = scores[np.arange(rows.size), best], scores[:, -1]
        gain = np.where(np.isfinite(plan), top - np.where(np.isfinite(plan), plan, 0.0), np.inf)
        gain = np.where(np.isfinite(top), gain, -np.inf)
        ref = np.where(gain > margin[rows], cand[np.arange(rows.size), best], y_target[rows])

        got = choose_offsets(order, rows, grid, stay_allowed, a["x"], a["y"], y_target, a["hx"], a["hy"], a["lo"],
                             a["hi"], a["vx"], v0, a["s0"], headway, a["b"], margin, room_l, room_r, a["is_ego"],
                             ignore, kerb_bias, cut_in, ego_y, ego_hy, half_width, edge, min_gap)
        assert np.array_equal(got, ref)
