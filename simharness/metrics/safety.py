"""Safety of one agent (the ego) among the others: collisions, time-to-collision, near misses, gaps.

All pure functions of Scene arrays with valid masks. Collisions are oriented-box
overlaps (simharness.metrics.collisions), never a simulator's flag.

Time-to-collision is computed by constant-velocity extrapolation of the two
oriented boxes (headings held), sampled every `step` seconds up to `horizon`:
the first sampled time at which the boxes overlap (resolution `step`), 0 when
they overlap now, +inf when they do not within the horizon.
"""

from __future__ import annotations

import numpy as np

from simharness.metrics.collisions import boxes_overlap, collision_events
from simharness.scene import AgentType


def ego_contact(
    xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray, valid: np.ndarray, ego: int,
) -> np.ndarray:
    """Whether each agent's box overlaps the ego's box, per frame.

    xy (N, T, 2) m, heading (N, T) rad, length/width (N,) m, valid (N, T) -> (N, T) bool; the ego row is False.
    """
    n, t = valid.shape
    out = np.zeros((n, t), bool)
    if ego < 0:
        return out
    both = valid & valid[ego][None, :]
    both[ego] = False
    # Prune by bounding circles before the separating-axis test.
    reach = 0.5 * np.hypot(length, width) + 0.5 * np.hypot(length[ego], width[ego])
    dist = np.linalg.norm(xy - xy[ego][None], axis=-1)
    rows, cols = np.nonzero(both & (dist <= reach[:, None]))
    hit = boxes_overlap(xy[rows, cols], heading[rows, cols], length[rows], width[rows],
                        xy[ego, cols], heading[ego, cols], length[ego], width[ego])
    out[rows[hit], cols[hit]] = True
    return out


def spell_onsets(flag: np.ndarray) -> np.ndarray:
    """First frame of each run of True along the last axis: (..., T) bool -> (..., T) bool."""
    prev = np.concatenate([np.zeros_like(flag[..., :1]), flag[..., :-1]], -1)
    return flag & ~prev


def collisions_by_type(contact: np.ndarray, agent_type: np.ndarray) -> dict[str, int]:
    """Distinct ego collisions (contact spells) by the other agent's type.

    contact (N, T) bool from `ego_contact`, agent_type (N,) int8 -> {type label: count}, every type listed.
    """
    per_agent = spell_onsets(contact).sum(-1)  # (N,)
    counts = np.bincount(agent_type.astype(int), weights=per_agent, minlength=len(AgentType))
    return {t.label: int(counts[t]) for t in AgentType}


def time_to_collision(
    xy: np.ndarray, velocity: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray,
    valid: np.ndarray, ego: int, horizon: float = 5.0, step: float = 0.1,
) -> np.ndarray:
    """Ego-to-agent time-to-collision by constant-velocity extrapolation of oriented boxes.

    xy (N, T, 2) m, velocity (N, T, 2) m/s, heading (N, T) rad, length/width (N,) m, valid (N, T)
    -> (N, T) float32 seconds: 0 if overlapping now, first sampled overlap time, +inf if none
    within `horizon` (and for the ego row and invalid entries).
    """
    n, t = valid.shape
    ttc = np.full((n, t), np.inf, np.float32)
    if ego < 0:
        return ttc
    taus = np.arange(0.0, horizon + 1e-9, step)  # (K,)
    both = valid & valid[ego][None, :]
    both[ego] = False
    rel_v = np.linalg.norm(velocity - velocity[ego][None], axis=-1)
    reach = (0.5 * np.hypot(length, width) + 0.5 * np.hypot(length[ego], width[ego]))[:, None] + rel_v * horizon
    dist = np.linalg.norm(xy - xy[ego][None], axis=-1)
    rows, cols = np.nonzero(both & (dist <= reach))
    if rows.size == 0:
        return ttc
    shape = (rows.size, taus.size)
    pa = xy[rows, cols][:, None] + velocity[rows, cols][:, None] * taus[None, :, None]  # (P, K, 2)
    pe = xy[ego, cols][:, None] + velocity[ego, cols][:, None] * taus[None, :, None]
    hit = boxes_overlap(pa, np.broadcast_to(heading[rows, cols][:, None], shape),
                        np.broadcast_to(length[rows][:, None], shape), np.broadcast_to(width[rows][:, None], shape),
                        pe, np.broadcast_to(heading[ego, cols][:, None], shape),
                        np.full(shape, length[ego]), np.full(shape, width[ego]))  # (P, K)
    first = np.where(hit.any(-1), taus[np.argmax(hit, -1)], np.inf)
    ttc[rows, cols] = first
    return ttc


TTC_BEHIND_DEG = 150.0  # an agent whose bearing off the ego's heading exceeds this is behind it (nuPlan's)
TTC_STOPPED = 5e-3  # m/s: an ego this slow is standing; nothing closing in on it is a near miss of its making


def ttc_relevant(xy: np.ndarray, heading: np.ndarray, speed: np.ndarray, valid: np.ndarray, ego: int,
                 behind_deg: float = TTC_BEHIND_DEG, stopped: float = TTC_STOPPED) -> np.ndarray:
    """Which agents' time-to-collision counts, as nuPlan's TTC metric: agents not behind the ego (the bearing of
    their centre off the ego's heading at most `behind_deg`: a lane-less road, so beside counts as ahead), while
    the ego moves (speed above `stopped` m/s). Closing in on an ego from behind, or on one standing, is not a near
    miss of the ego's making.

    xy (N, T, 2) m, heading (N, T) rad (the ego's row used), speed (N, T) m/s, valid (N, T) -> (N, T) bool;
    the ego row is False.
    """
    out = np.zeros(valid.shape, bool)
    if ego < 0:
        return out
    rel = xy - xy[ego][None]  # (N, T, 2)
    fwd = np.stack([np.cos(heading[ego]), np.sin(heading[ego])], -1)  # (T, 2)
    along = np.einsum("ntd,td->nt", rel, fwd)
    dist = np.linalg.norm(rel, axis=-1)
    not_behind = along >= -np.cos(np.deg2rad(180.0 - behind_deg)) * dist
    out = valid & valid[ego][None] & not_behind & (speed[ego] > stopped)[None]
    out[ego] = False
    return out


def near_misses(ttc: np.ndarray, contact: np.ndarray, valid: np.ndarray, threshold: float = 1.5) -> np.ndarray:
    """Near-miss events: spells of TTC < threshold (per agent) that never reach contact.

    ttc (N, T) s, contact (N, T) bool, valid (N, T) -> (N, T) bool, True at the first frame of each near miss.
    """
    close = (ttc < threshold) & valid
    onset = spell_onsets(close)
    spell_id = np.cumsum(onset, -1) * close  # (N, T) 1-based id of the spell each close frame is in, 0 outside
    n, t = close.shape
    # A spell is spoiled if any of its frames is a contact: mark (agent, spell id) pairs.
    spoiled = np.zeros((n, t + 1), bool)
    r, c = np.nonzero(close & contact)
    spoiled[r, spell_id[r, c]] = True
    return onset & ~np.take_along_axis(spoiled, spell_id, -1)


def min_gap(
    xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray, valid: np.ndarray, ego: int,
) -> np.ndarray:
    """Gap between the ego's box and each agent's box, per frame (separating-axis lower bound).

    The largest separation along the four box axes: exact when the boxes are separated face to face,
    a lower bound corner to corner; 0 when they overlap.
    xy (N, T, 2), heading (N, T), length/width (N,), valid (N, T) -> (N, T) float32 m, +inf where not both valid.
    """
    n, t = valid.shape
    gap = np.full((n, t), np.inf, np.float32)
    if ego < 0:
        return gap
    both = valid & valid[ego][None, :]
    both[ego] = False
    rows, cols = np.nonzero(both)
    ha, hb = heading[rows, cols], heading[ego, cols]
    axes = np.stack([np.stack([np.cos(h), np.sin(h)], -1) for h in (ha, ha + np.pi / 2, hb, hb + np.pi / 2)], 1)
    centre = np.einsum("pkd,pd->pk", axes, xy[ego, cols] - xy[rows, cols])  # (P, 4) ego centre along each axis

    def half_extent(h: np.ndarray, le: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """Projection radius of a box of heading h (P,) onto each of the 4 axes -> (P, 4)."""
        fwd = np.stack([np.cos(h), np.sin(h)], -1)
        left = np.stack([-np.sin(h), np.cos(h)], -1)
        return (np.abs(np.einsum("pkd,pd->pk", axes, fwd)) * le[:, None] / 2
                + np.abs(np.einsum("pkd,pd->pk", axes, left)) * wi[:, None] / 2)

    sep = np.abs(centre) - half_extent(ha, length[rows], width[rows]) - half_extent(
        hb, np.full(rows.size, length[ego]), np.full(rows.size, width[ego]))
    gap[rows, cols] = np.maximum(sep.max(-1), 0.0)
    return gap


def background_collisions(
    xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray, valid: np.ndarray, ego: int = -1,
) -> np.ndarray:
    """Distinct collisions among background agents (pairs without the ego).

    Shapes as `ego_contact` -> (E, 3) int (frame, row_i, row_j), i < j, counted once per contact spell.
    """
    events = collision_events(xy, heading, length, width, valid)
    keep = (events[:, 1] != ego) & (events[:, 2] != ego)
    return events[keep]


def phantom_braking(xy: np.ndarray, speed: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray,
                    valid: np.ndarray, ego: int, dt: float, window: float = 1.5, hard_brake: float = 2.5,
                    stopped: float = 0.5, headway: float = 1.5, standstill: float = 4.0) -> np.ndarray:
    """Frames at which the ego brakes hard, or stands, with nothing ahead of it that calls for it.

    Hard braking: speed lost over the last `window` s above `hard_brake` m/s^2 on average; standing:
    speed under `stopped` m/s. Nothing ahead: every time in the window, no agent overlapping the ego's
    lateral band (box heading frame) has its rear within `standstill` + `headway` x ego speed of the
    ego's front. A follower that runs into such an ego was given no reason to expect the stop.
    xy (N, T, 2) m, speed (N, T) m/s, heading (N, T) rad (box heading), length/width (N,) m, valid (N, T)
    -> (T,) bool (False where the ego is absent).
    """
    n, t = valid.shape
    out = np.zeros(t, bool)
    if ego < 0:
        return out
    k = max(1, int(round(window / dt)))
    ve = np.where(valid[ego], speed[ego], 0.0)
    back = np.concatenate([np.full(k, np.nan), ve[:-k]]) if t > k else np.full(t, np.nan)
    braking = np.nan_to_num((back - ve) / (k * dt), nan=0.0) > hard_brake
    standing = ve < stopped
    fwd = np.stack([np.cos(heading[ego]), np.sin(heading[ego])], -1)  # (T, 2)
    rel = xy - xy[ego][None]  # (N, T, 2)
    along = np.einsum("ntd,td->nt", rel, fwd)
    lat = rel[..., 1] * fwd[None, :, 0] - rel[..., 0] * fwd[None, :, 1]
    band = np.abs(lat) < (width[:, None] + width[ego]) / 2
    gap = along - (length[:, None] + length[ego]) / 2
    need = standstill + headway * ve  # (T,)
    blocked = (valid & valid[ego][None] & band & (gap > -0.5) & (gap < need[None])).any(0)
    # Blocked at any time in the window (a leader that just left still explains the braking).
    cum = np.concatenate([[0], np.cumsum(blocked)])
    recent = (cum[1:] - cum[np.maximum(np.arange(t) + 1 - k - 1, 0)]) > 0
    return valid[ego] & (braking | standing) & ~recent


def ego_at_fault(onsets: np.ndarray, xy: np.ndarray, velocity: np.ndarray, heading: np.ndarray,
                 width: np.ndarray, valid: np.ndarray, ego: int, flow_radius: float = 30.0,
                 phantom: np.ndarray | None = None) -> np.ndarray:
    """Which ego collisions the ego caused, judged in the local traffic-flow frame at the onset.

    Flow direction: mean heading of the valid agents within `flow_radius` m of the ego that move the
    ego's way. Contact in line (lateral overlap in that frame): the ego is at fault if the other is ahead
    and the ego was faster along the flow (it ran into it); hit from behind, only if it was braking or
    standing for nothing (`phantom`, from `phantom_braking`). A contact behind the ego's centre is in line
    only if the other was in line the frame before too (it came from behind): one that came from the side
    into the ego's rear quarter, as a pedestrian walking into a car that brakes, is a side contact.
    Contact side by side: the ego is at fault if it moved across the flow towards the other faster than
    the other moved towards it (so being cut into while holding its line is not its fault).

    onsets (N, T) bool (first frames of contact, e.g. `spell_onsets(ego_contact(...))`), xy (N, T, 2) m,
    velocity (N, T, 2) m/s, heading (N, T) rad, width (N,) m, valid (N, T), phantom (T,) bool or None
    -> (N, T) bool, within onsets.
    """
    rows, cols = np.nonzero(onsets)
    out = np.zeros_like(onsets, dtype=bool)
    if ego < 0 or rows.size == 0:
        return out
    # Flow axis per onset frame, from the neighbours' headings (vectorised over the onset frames).
    he = heading[ego, cols]  # (P,)
    near = valid[:, cols] & (np.linalg.norm(xy[:, cols] - xy[ego, cols][None], axis=-1) <= flow_radius)  # (N, P)
    same_way = np.cos(heading[:, cols] - he[None]) > 0
    w = (near & same_way).astype(np.float64)
    axis = np.stack([(w * np.cos(heading[:, cols])).sum(0), (w * np.sin(heading[:, cols])).sum(0)], -1)  # (P, 2)
    axis /= np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-9)
    normal = np.stack([-axis[:, 1], axis[:, 0]], -1)
    rel = xy[rows, cols] - xy[ego, cols]
    along, lat = np.einsum("pd,pd->p", rel, axis), np.einsum("pd,pd->p", rel, normal)
    # The frame before contact (the onset's own where either is absent then), in the onset's flow frame.
    before = np.maximum(cols - 1, 0)
    before = np.where((cols > 0) & valid[rows, before] & valid[ego, before], before, cols)
    lat_before = np.einsum("pd,pd->p", xy[rows, before] - xy[ego, before], normal)
    ve, vo = velocity[ego, cols], velocity[rows, cols]
    band = (width[rows] + width[ego]) / 2 - 0.1
    from_side = (along <= 0) & (np.abs(lat_before) >= band)  # into the rear quarter from the side
    in_line = (np.abs(lat) < band) & ~from_side
    ran_into = (along > 0) & (np.einsum("pd,pd->p", ve, axis) > np.einsum("pd,pd->p", vo, axis))
    if phantom is not None:  # rear-ended while braking or standing for nothing: the ego's doing
        ran_into |= (along <= 0) & phantom[cols]
    side = np.sign(np.where(from_side, lat_before, lat))
    ego_in = np.einsum("pd,pd->p", ve, normal) * side  # ego moving across the flow towards the other
    other_in = -np.einsum("pd,pd->p", vo, normal) * side  # other moving across the flow towards the ego
    out[rows, cols] = np.where(in_line, ran_into, ego_in > other_in)
    return out
