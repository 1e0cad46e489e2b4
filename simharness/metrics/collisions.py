"""Collisions as oriented-box overlaps, computed from the Scene for every backend alike.

Never trusts a simulator's own flag: two agents collide at a frame when their
footprint rectangles (centre, heading, length, width) overlap by the
separating-axis test. Vectorised over all pairs of a frame; candidate pairs
are first pruned by bounding circles.
"""

from __future__ import annotations

import numpy as np

from simharness.scene import Scene


def box_corners(xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Rectangle corners.

    xy (..., 2), heading (...), length (...), width (...) -> (..., 4, 2), counter-clockwise.
    """
    c, s = np.cos(heading), np.sin(heading)
    fwd = np.stack([c, s], -1) * (length / 2)[..., None]
    left = np.stack([-s, c], -1) * (width / 2)[..., None]
    xy = np.asarray(xy)
    return np.stack([xy + fwd + left, xy - fwd + left, xy - fwd - left, xy + fwd - left], -2)


def boxes_overlap(
    xy_a: np.ndarray, heading_a: np.ndarray, length_a: np.ndarray, width_a: np.ndarray,
    xy_b: np.ndarray, heading_b: np.ndarray, length_b: np.ndarray, width_b: np.ndarray,
    margin: float = 0.0,
) -> np.ndarray:
    """Separating-axis overlap test of oriented rectangles, broadcast over leading dims.

    xy_* (..., 2); heading_*, length_*, width_* (...) -> (...) bool.
    Touching edges (zero-area contact) count as overlap; `margin` (m) inflates both boxes.
    """
    la, wa = np.asarray(length_a) + 2 * margin, np.asarray(width_a) + 2 * margin
    lb, wb = np.asarray(length_b) + 2 * margin, np.asarray(width_b) + 2 * margin
    ca = box_corners(xy_a, heading_a, la, wa)  # (..., 4, 2)
    cb = box_corners(xy_b, heading_b, lb, wb)
    ha, hb = np.asarray(heading_a), np.asarray(heading_b)
    axes = np.stack([np.stack([np.cos(ha), np.sin(ha)], -1), np.stack([-np.sin(ha), np.cos(ha)], -1),
                     np.stack([np.cos(hb), np.sin(hb)], -1), np.stack([-np.sin(hb), np.cos(hb)], -1)],
                    -2)  # (..., 4 axes, 2)
    pa = np.einsum("...kd,...ad->...ak", ca, axes)  # (..., 4 axes, 4 corners)
    pb = np.einsum("...kd,...ad->...ak", cb, axes)
    separated = (pa.max(-1) < pb.min(-1) - 1e-9) | (pb.max(-1) < pa.min(-1) - 1e-9)
    return ~separated.any(-1)


def frame_collision_pairs(
    xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray, valid: np.ndarray,
    margin: float = 0.0,
) -> np.ndarray:
    """Overlapping pairs among the agents of one frame.

    xy (N, 2), heading (N,), length (N,), width (N,), valid (N,) -> (P, 2) int rows i < j.
    """
    idx = np.flatnonzero(valid)
    if idx.size < 2:
        return np.zeros((0, 2), int)
    p = xy[idx].astype(np.float64)
    radius = 0.5 * np.hypot(length[idx], width[idx]) + margin
    i, j = np.triu_indices(idx.size, 1)
    near = np.hypot(*(p[i] - p[j]).T) <= radius[i] + radius[j]
    i, j = i[near], j[near]
    hit = boxes_overlap(p[i], heading[idx][i], length[idx][i], width[idx][i],
                        p[j], heading[idx][j], length[idx][j], width[idx][j], margin)
    return np.stack([idx[i[hit]], idx[j[hit]]], -1)


def collision_matrix(
    xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray, valid: np.ndarray,
    rows: np.ndarray | None = None, margin: float = 0.0,
) -> np.ndarray:
    """Per agent and frame, whether it overlaps any other valid agent.

    xy (N, T, 2), heading (N, T), length (N,), width (N,), valid (N, T) -> (N, T) bool.
    rows: optional (R,) agents to test against everyone (e.g. [ego]); then the result is (R, T).
    """
    n, t = valid.shape
    rows = np.arange(n) if rows is None else np.asarray(rows)
    out = np.zeros((rows.size, t), bool)
    for f in range(t):  # frames, not agents: pairs inside a frame are vectorised
        pairs = frame_collision_pairs(xy[:, f], heading[:, f], length, width, valid[:, f], margin)
        hit = np.zeros(n, bool)
        hit[pairs.ravel()] = True
        out[:, f] = hit[rows]
    return out


def collision_events(
    xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray, valid: np.ndarray,
) -> np.ndarray:
    """Distinct collisions: a pair counted once at the first frame of each contact spell.

    Shapes as `collision_matrix`. Returns (E, 3) int: (frame, row_i, row_j) with i < j.
    """
    events, prev = [], set()
    for f in range(valid.shape[1]):
        pairs = frame_collision_pairs(xy[:, f], heading[:, f], length, width, valid[:, f])
        now = {(int(a), int(b)) for a, b in pairs}
        events += [(f, a, b) for a, b in sorted(now - prev)]
        prev = now
    return np.asarray(events, dtype=int).reshape(-1, 3)


def box_heading(scene: Scene) -> np.ndarray:
    """(N, T) rad: the heading the simulator's own bodies have, which collision boxes must use.

    SUMO's sub-lane model moves lane-aligned bodies sideways: its recorded heading of motion turns by
    atan(lateral / forward speed), 30 degrees for a car edging over at walking pace, which no body
    does; boxes turned that way overlap neighbours SUMO (and the `sim_heading` boxes) keep apart.
    Backends without `sim_heading` (highway) record the body heading itself.
    """
    return scene.extra["sim_heading"] if "sim_heading" in scene.extra else scene.heading
