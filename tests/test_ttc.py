"""The reward's compiled time to collision (through `ego_safety`) against the numpy formulation it replaced."""

from __future__ import annotations

import numpy as np

from simharness.envs import reward
from simharness.metrics.collisions import boxes_overlap
from simharness.sim.base import Frame


def may_overlap(rel, ha, la, wa, hb, lb, wb):  # noqa: ANN001, ANN201
    """The (P,) numpy four-axis bound."""
    ca, sa, cb, sb = np.cos(ha), np.sin(ha), np.cos(hb), np.sin(hb)
    cos_d, sin_d = np.abs(ca * cb + sa * sb), np.abs(sa * cb - ca * sb)
    la, wa, lb, wb = 0.5 * la, 0.5 * wa, 0.5 * lb, 0.5 * wb
    x, y = rel[:, 0], rel[:, 1]
    ok = np.abs(x * ca + y * sa) <= la + lb * cos_d + wb * sin_d + 1e-6
    ok &= np.abs(y * ca - x * sa) <= wa + lb * sin_d + wb * cos_d + 1e-6
    ok &= np.abs(x * cb + y * sb) <= lb + la * cos_d + wa * sin_d + 1e-6
    ok &= np.abs(y * cb - x * sb) <= wb + la * sin_d + wa * cos_d + 1e-6
    return ok


def numpy_min_ttc(frame, xy, heading, length, width, rel, d, reach) -> float:  # noqa: ANN001
    """The (n,) / (P, K) numpy version: quadratic window, sampled times, four-axis bound, separating axes."""
    e = frame.ego
    speed = frame.speed.astype(np.float64)
    vel = speed[:, None] * np.stack([np.cos(heading), np.sin(heading)], -1)
    dv = vel - vel[e]
    a, b, c = (dv**2).sum(-1), (rel * dv).sum(-1), d**2 - reach**2
    disc = b**2 - a * c
    ok = (disc >= 0) & ((c <= 0) | (a > 0))
    ok[e] = False
    root = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = np.where(c <= 0, 0.0, (-b - root) / a)
        hi = np.where(a > 0, (-b + root) / a, np.inf)
    ok &= (hi >= 0) & (lo <= reward.TTC_HORIZON)
    rows = np.flatnonzero(ok)
    taus = reward._TAUS
    window = (taus[None] >= lo[rows, None] - 1e-6) & (taus[None] <= hi[rows, None] + 1e-6)
    p, k = np.nonzero(window)
    r, tau = rows[p], taus[k]
    pa, pe = xy[r] + vel[r] * tau[:, None], xy[e] + vel[e] * tau[:, None]
    keep = np.flatnonzero(may_overlap(pa - pe, heading[r], length[r], width[r], heading[e], length[e], width[e]))
    r, tau = r[keep], tau[keep]
    hit = boxes_overlap(pa[keep], heading[r], length[r], width[r], pe[keep], np.full(r.size, heading[e]),
                        np.full(r.size, length[e]), np.full(r.size, width[e]))
    return float(tau[hit].min()) if hit.any() else reward.TTC_CAP


def test_min_ttc_matches_the_numpy_formulation():
    """Random frames around the ego (standing agents, rounded positions, zero headings: the edge cases), the
    same first sampled time of overlap, TTC_CAP when none."""
    rng = np.random.default_rng(4)
    found = 0
    for it in range(400):
        n = int(rng.integers(2, 40))
        xy = rng.uniform(-25, 25, (n, 2)).astype(np.float32).astype(np.float64)
        if it % 2:
            xy = np.round(xy, 1).astype(np.float32).astype(np.float64)  # (a Frame holds float32)
        heading = rng.uniform(-0.6, 0.6, n).astype(np.float32).astype(np.float64)
        heading[rng.random(n) < 0.4] = 0.0
        speed = rng.choice([0.0, 3.0, 8.0, 14.0], n).astype(np.float32)
        length = rng.choice([0.5, 1.8, 4.5, 12.0], n).astype(np.float32)
        width = rng.choice([0.5, 0.8, 1.8, 2.5], n).astype(np.float32)
        frame = Frame(t=0.0, agent_id=np.array([f"a{i}" for i in range(n)]), agent_type=np.zeros(n, np.int8),
                      xy=xy.astype(np.float32), heading=heading.astype(np.float32), speed=speed, length=length,
                      width=width, ego=int(rng.integers(n)))
        e = frame.ego
        length, width = length.astype(np.float64), width.astype(np.float64)
        rel = xy - xy[e]
        d = np.hypot(rel[:, 0], rel[:, 1])
        reach = 0.5 * np.hypot(length, width) + 0.5 * np.hypot(length[e], width[e]) + 1e-6
        ref = numpy_min_ttc(frame, xy, heading, length, width, rel, d, reach)
        safe = reward.ego_safety(frame)
        assert safe.ttc == ref and safe.contact == (ref == 0.0)
        found += ref < reward.TTC_CAP
    assert found > 50  # the test sees collisions ahead, not only free road
