"""Crossing pedestrians that sub-lane traffic sees: small standing vehicles the harness walks across.

Why not SUMO's own pedestrians: on a shared carriageway or at unsignalised crossings, sub-lane
vehicles judge crossing conflicts from the lane centre and hit them (tens of collisions
per 400 s). Here a crossing pedestrian is a SUMO vehicle of the "pedestrian" vType standing on the
carriageway (speed 0), moved sideways by the harness at walking speed. Every vehicle's sub-lane
model treats it as an obstacle in its lateral band, and the pedestrian steps into the next band
only when no vehicle there would reach it within `GAP_TIME` (gap acceptance, as people do).
On a two-way road it crosses one carriageway, then the other (a new SUMO vehicle, same public id).
Pedestrians walking along the road are ordinary flows of the same vType demand.py.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from simharness.scenario import ScenarioSpec
from simharness.sim.sumo.net import Carriageway, Network
from simharness.sim.sumo.traffic import Traffic

GAP_TIME = 3.0  # s: a vehicle closer than this (plus a margin) to the next band blocks a step
MARGIN = 0.4  # m: lateral clearance kept to vehicles when stepping
TAIL_SLACK = 2.0  # m: extra reach behind a turning vehicle (its body follows a curve; measured 1.3 m short)
CURB = 0.35  # m: a pedestrian stands this far inside the carriageway edge
SLOT = 0.6  # m along the road between two crossers on one carriageway (a pedestrian is 0.5 m long)
SLOT_SHIFTS = (0.0, SLOT, -SLOT, 2 * SLOT, -2 * SLOT)
PREFIX = "xped"  # SUMO ids "xped<k>.<carriageway>"; recorded as "xped<k>"


@dataclasses.dataclass
class Crosser:
    public: str
    vid: str
    cw: Carriageway  # carriageway it is crossing now
    pos: float  # metres along cw from its start (centre line of the crossing)
    lat: float  # current offset from cw centre, + left
    target: float  # offset where this carriageway's crossing ends
    then: Carriageway | None  # the opposite carriageway still to cross
    prev_lat: float = 0.0
    waited: float = 0.0
    go: bool = False
    home: float | None = None  # pos it meant to cross at (slots shift pos around it)


def _opposite(net: Network, cw: Carriageway) -> Carriageway | None:
    """The carriageway of the other direction on the same road (shares cw's left edge)."""
    for o in net.entries:
        if np.allclose(o.start, cw.end) and np.allclose(o.end, cw.start):
            return o
    if cw.edge.endswith("_in"):  # intersection arms: the outbound edge of the same arm
        return Carriageway(cw.edge[:-3] + "_out", cw.end, cw.start, cw.width, cw.centre_offset)
    return None


class Crossings:
    """Poisson arrivals of crossing pedestrians and their walk across, driven once per SUMO step."""

    def __init__(self, spec: ScenarioSpec, net: Network, rng: np.random.Generator) -> None:
        self.rate = spec.pedestrians.crossing_rate * spec.demand_scale / 3600.0  # per second
        self.speed = spec.pedestrians.speed
        self.net, self.rng = net, rng
        self.ped_type = "pedestrian__1"
        self.active: list[Crosser] = []
        self.waiting: list[Crosser] = []  # on the sidewalk, not yet in SUMO
        self._count = 0
        self._next = rng.exponential(1.0 / self.rate) if self.rate > 0 else math.inf
        self._by_vid: dict[str, Crosser] = {}
        self._routes: set[str] = set()
        self._clock = 0.0
        self.look_ahead = spec.dt  # s of walking covered by one gap decision

    # ------------------------------------------------------------------ ids
    @staticmethod
    def public_id(vid: str) -> str:
        """The recorded id: a crosser is one SUMO vehicle per carriageway ("xped3.0", "xped3.1" -> "xped3")."""
        return vid.rsplit(".", 1)[0] if vid.startswith(PREFIX) else vid

    def override_motion(self, ids: tuple[str, ...], heading: np.ndarray, speed: np.ndarray, dt: float) -> None:
        """Crossers move sideways while SUMO reports them standing: record their real motion.

        ids (n,), heading (n,) rad, speed (n,) m/s of every vehicle; heading and speed are changed in place.
        """
        for vid, c in self._by_vid.items():  # a few crossers: look each up in the id tuple (C speed)
            try:
                i = ids.index(vid)
            except ValueError:
                continue
            d = c.cw.direction
            side = 1.0 if c.target > c.lat or (c.target >= c.prev_lat and c.lat == c.target) else -1.0
            heading[i] = math.atan2(d[0], -d[1]) if side > 0 else math.atan2(-d[0], d[1])
            speed[i] = abs(c.lat - c.prev_lat) / dt
            c.prev_lat = c.lat

    def mark(self) -> None:
        """Forget motion so far (after unrecorded steps), so the next recorded speed covers one frame."""
        for c in self.active:
            c.prev_lat = c.lat

    # ------------------------------------------------------------------ stepping
    def step(self, libsumo: object, dt: float, look: bool, traffic: Callable[[], Traffic]) -> None:
        """One SUMO step's worth: spawn arrivals, move crossers whose next band is clear.

        look: decide on gaps now (once per recorded frame; in between, a crosser keeps the decision
        it took, which is what a person does over 0.2 s). traffic: every vehicle now, called only
        when a decision needs it (the recorded path hands over the frame it has just read).
        """
        if self.rate <= 0 and not self.active and not self.waiting:
            return
        self._clock += dt
        while self._next <= self._clock:
            self._next += self.rng.exponential(1.0 / self.rate)
            self.waiting.append(self._new_crosser())
        if not self.active and not self.waiting:
            return
        gaps = _Gaps(traffic(), self._by_vid) if look else None
        reach = self.speed * self.look_ahead
        if gaps is not None and self.active:  # SUMO may have removed one (teleport after a long wait): forget it
            present = set(gaps.ids)
            for c in [c for c in self.active if c.vid not in present]:
                self.active.remove(c)
                self._by_vid.pop(c.vid, None)
        for c in list(self.waiting):
            if gaps is not None and self._take_slot(c) and gaps.clear(c.cw, c.pos, c.lat, c.lat):
                self._enter(libsumo, c)
                self.waiting.remove(c)
        for c in list(self.active):
            if abs(c.target - c.lat) < 1e-6:
                self._leave(libsumo, c)
                continue
            if gaps is not None:  # decide for the frame: is the band up to one frame's walk ahead clear?
                ahead = c.lat + math.copysign(min(reach, abs(c.target - c.lat)), c.target - c.lat)
                c.go = gaps.clear(c.cw, c.pos, c.lat, ahead)
            if c.go:
                c.lat += math.copysign(min(self.speed * dt, abs(c.target - c.lat)), c.target - c.lat)
                c.waited = 0.0
            else:
                c.waited += dt
            self._place(libsumo, c)

    def _new_crosser(self) -> Crosser:
        self._count += 1
        entries = self.net.entries
        cw = entries[int(self.rng.integers(len(entries)))]
        if self.net.routes.get(f"r_{cw.edge}") == (cw.edge,):  # arterial: anywhere mid-block
            pos = float(self.rng.uniform(0.2, 0.8) * cw.length)
        else:  # intersection arm: a crossing 6 m before the junction
            pos = cw.length - cw.width - 6.0
        pos += float(self.rng.uniform(-1.5, 1.5))  # a crosswalk is 3 m wide: people do not queue in single file
        half = cw.width / 2 - CURB
        name = f"{PREFIX}{self._count}"
        return Crosser(name, f"{name}.0", cw, pos, -half, half, _opposite(self.net, cw))

    def _xy(self, c: Crosser) -> tuple[float, float, float]:
        """World front-bumper point and SUMO angle (deg) for a crosser at (pos, lat)."""
        d, r = c.cw.direction, c.cw.right
        p = c.cw.start + d * (c.pos + 0.25) + r * (c.cw.centre_offset - c.lat)
        return float(p[0]), float(p[1]), float(math.degrees(math.atan2(d[0], d[1])) % 360.0)

    def _take_slot(self, c: Crosser) -> bool:
        """Move c along its crosswalk (by at most 1.2 m) clear of the crossers already on its carriageway.

        Crossers ignore each other in gap checks (people pass each other; two facing the same way would
        otherwise wait on each other for ever), so they keep apart by never sharing a line across the road.
        """
        taken = np.array([o.pos for o in self.active if o.cw.edge == c.cw.edge], float)
        c.home = c.pos if c.home is None else c.home
        for shift in SLOT_SHIFTS:
            pos = c.home + shift
            if 0.5 < pos < c.cw.length - 0.5 and not np.any(np.abs(taken - pos) < SLOT):
                c.pos = pos
                return True
        return False

    def _enter(self, ls: object, c: Crosser) -> None:
        route = f"x_{c.cw.edge}"
        if route not in self._routes:
            ls.route.add(route, [c.cw.edge])
            self._routes.add(route)
        ls.vehicle.add(c.vid, route, typeID=self.ped_type, depart="now", departLane="0",
                       departPos=f"{c.pos:.2f}", departSpeed="0")
        ls.vehicle.setSpeedMode(c.vid, 0)
        ls.vehicle.setSpeed(c.vid, 0.0)
        ls.vehicle.setLaneChangeMode(c.vid, 0)
        c.prev_lat = c.lat
        self._place(ls, c)
        self.active.append(c)
        self._by_vid[c.vid] = c

    def _place(self, ls: object, c: Crosser) -> None:
        x, y, angle = self._xy(c)
        try:
            ls.vehicle.moveToXY(c.vid, c.cw.edge, -1, x, y, angle, 2)
        except ls.TraCIException:  # SUMO removed it this step (arrived or teleported): it leaves the road
            self.active.remove(c)
            self._by_vid.pop(c.vid, None)

    def _leave(self, ls: object, c: Crosser) -> None:
        """Reached the far edge of this carriageway: go on to the opposite one, or off the road."""
        if c.vid in ls.vehicle.getIDList():
            ls.vehicle.remove(c.vid)
        self.active.remove(c)
        self._by_vid.pop(c.vid, None)
        if c.then is not None:
            nxt = c.then
            half = nxt.width / 2 - CURB
            pos = nxt.length - c.pos  # same crossing line, measured along the other direction
            n = int(c.vid.rsplit(".", 1)[1]) + 1
            follow = Crosser(c.public, f"{c.public}.{n}", nxt, pos, half, -half, None)
            self.waiting.insert(0, follow)


class _Gaps:
    """Gap checks on one `Traffic` read, with each carriageway's projection computed once.

    Crossing pedestrians (`crossers`, SUMO ids) are no obstacle to each other: they keep apart by slots.
    """

    def __init__(self, traffic: Traffic, crossers: dict[str, Crosser]) -> None:
        self.traffic = traffic
        self.ids = traffic.ids
        self._others = np.ones(len(traffic.ids), bool)
        for vid in crossers:
            if vid in traffic.ids:
                self._others[traffic.ids.index(vid)] = False
        self._frames: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def _on(self, cw: Carriageway) -> tuple[np.ndarray, ...]:
        """Vehicles whose body touches cw's strip: (m,) indices, and the body's extent along cw (m, s_lo..s_hi,
        node-line frame like `pos`) and across it (m, lat_lo..lat_hi of its centre line, + left)."""
        if cw.edge not in self._frames:
            t = self.traffic
            rel_f, rel_r = t.front - cw.start, t.rear - cw.start
            s_f, s_r = rel_f @ cw.direction, rel_r @ cw.direction
            lat_f, lat_r = cw.centre_offset - rel_f @ cw.right, cw.centre_offset - rel_r @ cw.right
            lat_lo, lat_hi = np.minimum(lat_f, lat_r), np.maximum(lat_f, lat_r)
            # A turning body bends along its path: SUMO may put its tail more than a length back along the road.
            bent = np.abs(lat_f - lat_r) > 0.3
            s_lo = np.minimum(np.minimum(s_f, s_r), s_f - t.length) - TAIL_SLACK * bent
            s_hi = np.maximum(s_f, s_r)
            # On this carriageway (or crossing it in the junction): the opposite direction is not a gap.
            on = np.flatnonzero((lat_hi >= -cw.width / 2) & (lat_lo <= cw.width / 2) & self._others)
            self._frames[cw.edge] = (on, s_lo[on], s_hi[on], lat_lo[on], lat_hi[on])
        return self._frames[cw.edge]

    def clear(self, cw: Carriageway, pos: float, lat0: float, lat1: float) -> bool:
        """True when no vehicle overlaps, or would reach within GAP_TIME, the band from lat0 to lat1 at pos."""
        on, s_lo, s_hi, lat_lo, lat_hi = self._on(cw)
        t = self.traffic
        v, width = t.speed[on], t.width[on]
        lo, hi = min(lat0, lat1) - 0.25 - MARGIN, max(lat0, lat1) + 0.25 + MARGIN
        lateral = (lat_hi + width / 2 > lo) & (lat_lo - width / 2 < hi)
        # The body covers [s_lo, s_hi]; it blocks if it is beside pos now or reaches it within GAP_TIME.
        ahead = s_lo < pos + 0.25 + MARGIN
        reach = s_hi + v * GAP_TIME + 0.5 > pos - 0.25
        return not bool(np.any(lateral & ahead & reach))
