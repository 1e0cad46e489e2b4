"""libsumo read paths for recording, measured in one process on the dense arterial: getters against subscriptions.

Every recorded frame the SUMO backend reads position, angle, speed, lane and lateral lane position of
every vehicle. Two ways, alternated in blocks of frames over one run (same traffic for both):
- getters: one call per vehicle and variable, at recorded frames only (what `SumoSimulator` does);
- subscriptions: each vehicle subscribed to the same variables once, at the first recorded frame
  that sees it (results come back at once), `vehicle.getAllSubscriptionResults()` at recorded frames;
  SUMO evaluates subscriptions on every step, so their cost shows in the step time too.
  Crossing pedestrians (a few vehicles the harness removes itself) are read with getters: SUMO 1.28
  stops with "Vehicle ... is not known" when a subscribed vehicle is removed through TraCI.
A third block steps without reading (raw). CPU time of this process (robust to other load on the
machine); per recorded frame = `steps_per_frame` SUMO steps + the read.

    python bench/sumo_recording.py [--frames 600] [--block 50]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import libsumo  # noqa: E402
import numpy as np  # noqa: E402
from libsumo import constants as tc  # noqa: E402

from simharness.scenario import load_scenario  # noqa: E402
from simharness.sim.sumo import SumoSimulator  # noqa: E402
from simharness.sim.sumo_pedestrians import PREFIX  # noqa: E402

VARS = (tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_LANE_ID, tc.VAR_LANEPOSITION_LAT)


def read_getters() -> int:
    g = libsumo.vehicle
    ids = g.getIDList()
    n = len(ids)
    np.array([g.getPosition(v) for v in ids], np.float64).reshape(n, 2)
    np.fromiter((g.getAngle(v) for v in ids), np.float64, n)
    np.fromiter((g.getSpeed(v) for v in ids), np.float64, n)
    [g.getLaneID(v) for v in ids]
    np.fromiter((g.getLateralLanePosition(v) for v in ids), np.float64, n)
    return n


def read_subscriptions(subscribed: set[str]) -> int:
    g = libsumo.vehicle
    for v in set(g.getIDList()) - subscribed:
        if not v.startswith(PREFIX):
            g.subscribe(v, VARS)
            subscribed.add(v)
    rows = list(g.getAllSubscriptionResults().values())
    pos, ang, spd, lane, lat = VARS
    rows += [{pos: g.getPosition(v), ang: g.getAngle(v), spd: g.getSpeed(v), lane: g.getLaneID(v),
              lat: g.getLateralLanePosition(v)} for v in g.getIDList() if v.startswith(PREFIX)]
    n = len(rows)
    np.array([r[pos] for r in rows], np.float64).reshape(n, 2)
    np.fromiter((r[ang] for r in rows), np.float64, n)
    np.fromiter((r[spd] for r in rows), np.float64, n)
    [r[lane] for r in rows]
    np.fromiter((r[lat] for r in rows), np.float64, n)
    return n


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=600, help="recorded frames per read path")
    p.add_argument("--block", type=int, default=50, help="frames per block before switching path")
    args = p.parse_args()
    spec = load_scenario("sumo_arterial_dense")
    sim = SumoSimulator(spec)
    sim.reset(0)
    spf = spec.steps_per_frame
    cpu = {"raw": [0.0, 0.0], "getters": [0.0, 0.0], "subscriptions": [0.0, 0.0]}  # step s, read s
    agents = {k: 0 for k in cpu}
    subscribed: set[str] = set()
    for block in range(3 * args.frames // args.block):
        mode = ("raw", "getters", "subscriptions")[block % 3]
        for _ in range(args.block):
            t0 = time.process_time()
            sim.advance_unrecorded(1)  # one frame: the same simulation work as SumoSimulator.step
            t1 = time.process_time()
            n = read_getters() if mode == "getters" else (read_subscriptions(subscribed) if mode != "raw" else 0)
            t2 = time.process_time()
            cpu[mode][0] += t1 - t0
            cpu[mode][1] += t2 - t1
            agents[mode] += n
        if mode == "subscriptions":
            for v in subscribed & set(libsumo.vehicle.getIDList()):
                libsumo.vehicle.unsubscribe(v)
            subscribed.clear()
    sim.close()
    frames = args.frames
    raw_step = cpu["raw"][0] / frames * 1e3
    print(f"sumo_arterial_dense, {frames} recorded frames per path ({spf} SUMO steps each), blocks of {args.block}, "
          f"CPU time; {agents['getters'] / frames:.0f} vehicles per frame")
    print(f"  {'path':<14} {'steps ms/frame':>15} {'read ms/frame':>14} {'total':>8} {'recording cost':>15}")
    for mode, (step, read) in cpu.items():
        s, r = step / frames * 1e3, read / frames * 1e3
        print(f"  {mode:<14} {s:15.3f} {r:14.3f} {s + r:8.3f} {s + r - raw_step:12.3f} ms")
    g, s = (sum(cpu[m]) for m in ("getters", "subscriptions"))
    print(f"  subscriptions / getters total time: {s / g:.3f} (>1: getters faster); per vehicle read: getters "
          f"{cpu['getters'][1] / agents['getters'] * 1e6:.2f} us, subscriptions "
          f"{cpu['subscriptions'][1] / agents['subscriptions'] * 1e6:.2f} us")
    print(f"  load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
