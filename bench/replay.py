"""Replay backend speed against the highway backend, measured in one run.

A replay episode (a data set folder replayed, `log` and `reactive`) and a highway-backend episode of the same
length and about the same number of agents, each stepped with the same constant ego command; prints
milliseconds per episode, per frame and per agent-frame, and the ratio to the highway episode.

    .venv/bin/simharness import commonroad ../shared/data/commonroad_ngsim --out runs/data/ngsim
    .venv/bin/python bench/replay.py --data runs/data/ngsim --episodes 10
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from simharness.scenario import load_scenario  # noqa: E402
from simharness.sim import make_simulator  # noqa: E402
from simharness.sim.base import EgoCommand  # noqa: E402


def episode_cost(spec, seeds: range) -> tuple[float, float, float]:  # noqa: ANN001
    """Mean wall seconds of one episode's reset and of its steps, and mean agents per frame, over seeds."""
    sim = make_simulator(spec)
    resets, walls, agents = [], [], []
    for seed in seeds:
        t0 = time.perf_counter()
        frame = sim.reset(seed)
        t1 = time.perf_counter()
        count = [frame.num_agents]
        for _ in range(spec.num_frames - 1):
            frame = sim.step(EgoCommand(0.0, 0.0) if frame.ego >= 0 else None)
            count.append(frame.num_agents)
        resets.append(t1 - t0)
        walls.append(time.perf_counter() - t1)
        agents.append(np.mean(count))
    sim.close()
    return float(np.mean(resets)), float(np.mean(walls)), float(np.mean(agents))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="a data set folder (e.g. NGSIM imported from CommonRoad)")
    ap.add_argument("--episodes", type=int, default=10)
    args = ap.parse_args()
    seeds = range(args.episodes)
    rows = {}
    base = load_scenario(args.data)
    for mode in ("log", "reactive"):
        rows[f"replay {mode}"] = (episode_cost(base.with_overrides({"replay.mode": mode}), seeds), base)
    agents = rows["replay reactive"][0][2]
    # The highway scenario at the replay's length and frame rate, its demand scaled to about as many agents.
    hw = load_scenario("highway_mixed_dense").with_overrides({"duration": base.duration, "warmup": 20.0})
    _, _, hw_agents = episode_cost(hw.with_overrides({"duration": 1.0}), range(1))
    hw = hw.with_overrides({"demand_scale": float(np.clip(agents / max(hw_agents, 1.0), 0.05, 20.0))})
    rows["highway"] = (episode_cost(hw, seeds), hw)
    ref = rows["highway"][0][1]
    print(f"{'backend':<18}{'agents':>8}{'frames':>8}{'reset ms':>10}{'steps ms':>10}{'ms/frame':>10}"
          f"{'us/agent-frame':>16}{'steps x highway':>17}")
    for name, ((reset, wall, n), spec) in rows.items():
        frames = spec.num_frames
        print(f"{name:<18}{n:>8.1f}{frames:>8d}{1000 * reset:>10.1f}{1000 * wall:>10.1f}{1000 * wall / frames:>10.2f}"
              f"{1e6 * wall / frames / max(n, 1):>16.1f}{wall / ref:>17.2f}")
    print("(reset: replay picks the ego and builds the routes; highway fills the road and runs its warm-up)")


if __name__ == "__main__":
    main()
