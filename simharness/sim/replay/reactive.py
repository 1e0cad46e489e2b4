"""Reactive replay: recorded agents follow their own paths with an IDM-style speed control.

Each agent tracks the recording (its arc length and speed at that time along its own path) and brakes as the
intelligent driver model would for the nearest agent ahead of it inside its lateral band that has left its
own recording: the ego once it is elsewhere than its recording (behind it, or beside its path), and any agent
that is itself held back. Agents still on the recording already keep the gaps they were recorded with.

    a_track = (v_log(t) - v) / TAU + (s_log(t) - s) / TAU^2            (back to the recording)
    a_idm   = a_max (1 - (s* / gap)^2),  s* = s0 + v T + v dv / (2 sqrt(a_max b))   (the leader ahead)
    a       = min(a_track, a_idm), clipped to [-MAX_DECEL, a_max]

An agent that nothing holds back stays exactly on the recording (its state is the recorded one), so far from
the ego `reactive` is `log`; one that was held back catches up again at most as hard as `a_max`.
Vehicles (two-wheelers included: their narrow band lets them pass beside others, as they filter in the
recording) react to the ego and to each other; pedestrians react to the ego only (they walk in groups
side by side, which their recording already keeps apart).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simharness.scene import AgentType

TAU = 1.0  # s: how fast a held-back agent returns to its recorded speed and place
MAX_DECEL = 8.0  # m/s^2
BAND_MARGIN = 0.3  # m added to the half widths when deciding who is ahead in an agent's band
LOOK_AHEAD = 60.0  # m

# Per type: a_max (m/s^2), comfortable decel b (m/s^2), time headway T (s), standstill gap s0 (m).
IDM = np.array([
    (2.0, 3.0, 1.2, 2.0),  # car
    (1.2, 2.5, 1.5, 2.5),  # bus
    (1.2, 2.5, 1.5, 2.5),  # truck
    (1.8, 3.0, 1.0, 1.5),  # rickshaw
    (2.5, 3.5, 0.8, 1.0),  # motorcycle
    (2.2, 3.5, 0.8, 1.0),  # scooter
    (1.2, 2.5, 0.8, 1.0),  # bicycle
    (1.0, 2.0, 0.5, 0.5),  # pedestrian
    (2.0, 3.0, 1.2, 2.0),  # other
])


@dataclasses.dataclass
class ReactiveState:
    """Arc length s (N,) m and speed v (N,) m/s along each agent's path; on_log (N,): exactly on the recording."""

    s: np.ndarray
    v: np.ndarray
    on_log: np.ndarray


def idm_accel(xy: np.ndarray, heading: np.ndarray, speed: np.ndarray, length: np.ndarray, width: np.ndarray,
              agent_type: np.ndarray, active: np.ndarray, leaders: np.ndarray, ego: int) -> np.ndarray:
    """IDM acceleration term of every active agent for its nearest leader among `leaders`.

    xy (N, 2) m, heading (N,) rad, speed (N,) m/s, length / width (N,) m, agent_type (N,), active (N,) bool:
    the agents controlled; leaders (N,) bool: who they may brake for; ego: the ego's row (pedestrians brake for
    it alone), -1 for none.
    -> (N,) m/s^2, a_max (1 - (s*/gap)^2) for the nearest leader; +inf where there is no leader.
    """
    n = len(xy)
    out = np.full(n, np.inf)
    me = np.flatnonzero(active)
    cand = np.flatnonzero(leaders)
    if me.size == 0 or cand.size == 0:
        return out
    rel = xy[cand][None] - xy[me][:, None]  # (A, C, 2)
    c, s = np.cos(heading[me])[:, None], np.sin(heading[me])[:, None]
    along = rel[..., 0] * c + rel[..., 1] * s
    lat = rel[..., 1] * c - rel[..., 0] * s
    gap = along - (length[me][:, None] + length[cand][None]) / 2
    band = np.abs(lat) < (width[me][:, None] + width[cand][None]) / 2 + BAND_MARGIN
    lead = band & (along > 0) & (along < LOOK_AHEAD) & (me[:, None] != cand[None])
    walker = agent_type[me] == int(AgentType.PEDESTRIAN)
    lead &= ~walker[:, None] | (cand[None] == ego)
    if not lead.any():
        return out
    gap = np.where(lead, gap, np.inf)
    j = np.argmin(gap, 1)  # (A,)
    g = gap[np.arange(me.size), j]
    has = np.isfinite(g)
    p = IDM[agent_type[me]]
    a_max, b, t_head, s0 = p[:, 0], p[:, 1], p[:, 2], p[:, 3]
    v = speed[me].astype(np.float64)
    # The leader's speed along my heading.
    dh = heading[cand[j]] - heading[me]
    v_lead = speed[cand[j]] * np.cos(dh)
    s_star = s0 + np.maximum(v * t_head + v * (v - v_lead) / (2 * np.sqrt(a_max * b)), 0.0)
    acc = a_max * (1 - (s_star / np.maximum(g, 0.1)) ** 2)
    out[me] = np.where(has, acc, np.inf)
    return out


def track_accel(state: ReactiveState, s_log: np.ndarray, v_log: np.ndarray) -> np.ndarray:
    """(N,) m/s^2 back to the recording: s_log, v_log (N,) where the recording is at the next step."""
    return (v_log - state.v) / TAU + (s_log - state.s) / TAU**2


def a_max_of(agent_type: np.ndarray) -> np.ndarray:
    """(N,) m/s^2 acceleration limit by type."""
    return IDM[agent_type, 0]
