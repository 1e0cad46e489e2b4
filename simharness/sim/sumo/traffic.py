"""What the harness reads from libsumo: per-vehicle constants cached once, and one motion read per frame.

Measured on the recorded path: plain libsumo getters cost about 0.3 us a
call, less than subscriptions, which SUMO evaluates on every step (several per recorded frame) and
whose dict-of-dicts results still need a Python pass per vehicle. So each vehicle's constants (agent
type, length, width, public id) are read once, when it is first seen, into rows of growing arrays,
and a frame reads only what moves, with getters, and looks the constants up by row index.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from simharness.sim.sumo.demand import agent_type_of


class VehicleTable:
    """Constants of every vehicle seen so far, one row each (rows are never reused within a run).

    agent_type (rows,) int8; length, width (rows,) float64 metres; public (rows,) object: the id
    recorded for the vehicle (crossing pedestrians are several SUMO vehicles under one public id).
    """

    def __init__(self, public_id: Callable[[str], str], capacity: int = 1024) -> None:
        self._public_id = public_id
        self._row: dict[str, int] = {}
        self.agent_type = np.zeros(capacity, np.int8)
        self.length = np.zeros(capacity, np.float64)
        self.width = np.zeros(capacity, np.float64)
        self.public = np.empty(capacity, object)

    def rows(self, ls: object, ids: tuple[str, ...]) -> np.ndarray:
        """(n,) row of each id, reading the constants of vehicles not seen before (libsumo module `ls`)."""
        get = self._row.get
        rows = np.fromiter((get(v, -1) for v in ids), np.int64, len(ids))
        for i in np.flatnonzero(rows < 0).tolist():
            rows[i] = self._learn(ls, ids[i])
        return rows

    def _learn(self, ls: object, vid: str) -> int:
        row = len(self._row)
        if row == len(self.length):  # grow geometrically: amortised O(1) per vehicle
            for name in ("agent_type", "length", "width", "public"):
                old = getattr(self, name)
                new = np.zeros(2 * len(old), old.dtype) if old.dtype != object else np.empty(2 * len(old), object)
                new[:row] = old
                setattr(self, name, new)
        v = ls.vehicle
        self.agent_type[row] = int(agent_type_of(v.getTypeID(vid)))
        self.length[row], self.width[row] = v.getLength(vid), v.getWidth(vid)
        self.public[row] = self._public_id(vid)
        self._row[vid] = row
        return row


@dataclasses.dataclass(frozen=True)
class Traffic:
    """Every SUMO vehicle after SUMO step `step` (a count since start): what gap decisions need.

    ids (n,) SUMO ids; rows (n,) into the `VehicleTable`; front (n, 2) front-bumper xy, m;
    speed (n,) m/s; length, width (n,) m; rear (n, 2) rear-bumper xy, m: behind the front along
    SUMO's angle (a vehicle turning in a junction still sweeps the crosswalk behind it).
    """

    step: int
    ids: tuple[str, ...]
    rows: np.ndarray
    front: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    width: np.ndarray
    rear: np.ndarray


def rear_of(front: np.ndarray, angle: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(n, 2) rear bumper from (n, 2) front bumper, (n,) SUMO angle (deg clockwise from north), (n,) length (m)."""
    a = np.radians(angle)
    return front - np.stack([np.sin(a), np.cos(a)], -1) * length[:, None]


def read_traffic(ls: object, table: VehicleTable, step: int) -> Traffic:
    """Positions, angles and speeds of every vehicle now (three getters a vehicle; constants from `table`)."""
    v = ls.vehicle
    ids = v.getIDList()
    n = len(ids)
    rows = table.rows(ls, ids)
    front = np.array([v.getPosition(i) for i in ids], np.float64).reshape(n, 2)
    angle = np.fromiter((v.getAngle(i) for i in ids), np.float64, n)
    speed = np.fromiter((v.getSpeed(i) for i in ids), np.float64, n)
    length = table.length[rows]
    return Traffic(step, ids, rows, front, speed, length, table.width[rows], rear_of(front, angle, length))
