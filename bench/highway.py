"""highway-env backend figures, measured in one run.

1. Speed: agent-steps per second of `HeteroHighwayEnv` (this backend) against stock
   `highway-fast-v0` with the same number of agents and the same frequencies
   (simulation 10 Hz, policy 5 Hz), at 20, 50 and 100 agents.
2. The mixed dense scenario: density and heterogeneity (as `simharness stats` computes
   them), collisions among background agents per 1,000 agent-minutes (oriented-box
   overlaps from the recorded Scene), emergency stops, and lateral passes of large
   vehicles by two-wheelers.

Writes runs/bench/highway/{speed.png, frame.png, results.json}. Usage: python bench/highway.py [--seeds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from simharness.metrics.collisions import box_heading, collision_events  # noqa: E402
from simharness.scenario import load_scenario  # noqa: E402
from simharness.scene import AgentType  # noqa: E402
from simharness.sim import make_simulator, scene_from_frames  # noqa: E402
from simharness.sim.highway.simulator import HeteroHighwayEnv, config_from_spec  # noqa: E402
from simharness.stats import neighbours_within, types_per_frame  # noqa: E402

SIM_HZ, POLICY_HZ = 10, 5
SMALL = [int(AgentType.MOTORCYCLE), int(AgentType.SCOOTER), int(AgentType.BICYCLE)]
LARGE = [int(AgentType.BUS), int(AgentType.TRUCK), int(AgentType.CAR)]


def stock_rate(n_agents: int, env_steps: int, seed: int = 0) -> float:
    """Agent-steps per second of highway-fast-v0 with n_agents vehicles (ego included), all checked for collisions
    as highway-env does for its controlled vehicle only."""
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers the envs)

    env = gym.make("highway-fast-v0", config={"vehicles_count": n_agents - 1, "simulation_frequency": SIM_HZ,
                                              "policy_frequency": POLICY_HZ, "duration": 10_000, "lanes_count": 4})
    env.reset(seed=seed)
    agent_steps = 0
    t0 = time.perf_counter()
    for _ in range(env_steps):
        _, _, term, trunc, _ = env.step(1)  # IDLE
        agent_steps += len(env.unwrapped.road.vehicles) * (SIM_HZ // POLICY_HZ)
        if term or trunc:
            env.reset(seed=seed)
    rate = agent_steps / (time.perf_counter() - t0)
    env.close()
    return rate


def dense_rate(n_agents: int, env_steps: int, seed: int = 0) -> tuple[float, float]:
    """(agent-steps per second, mean agents) of HeteroHighwayEnv on the mixed scenario, road length set for n_agents."""
    spec = load_scenario("highway_mixed_dense")
    config = config_from_spec(spec)
    per_m = 0.2  # agents per metre the mixed scenario holds after its warm-up (measured below)
    config.update(road_length=max(50.0, n_agents / per_m), simulation_frequency=SIM_HZ,
                  policy_frequency=POLICY_HZ)
    env = HeteroHighwayEnv(config)
    env.reset(seed=seed)
    agent_steps, counts = 0, []
    t0 = time.perf_counter()
    for _ in range(env_steps):
        env.step(None)
        counts.append(env.traffic.state.n)
        agent_steps += env.traffic.state.n * (SIM_HZ // POLICY_HZ)
    rate = agent_steps / (time.perf_counter() - t0)
    env.close()
    return rate, float(np.mean(counts))


def passes(scene, small: list[int], large: list[int]) -> int:
    """Times a small agent goes from behind a large one to ahead of it while both are on the road."""
    s = np.flatnonzero(np.isin(scene.agent_type, small))
    g = np.flatnonzero(np.isin(scene.agent_type, large))
    x = scene.xy[..., 0]
    both = scene.valid[s][:, None] & scene.valid[g][None, :]  # (S, G, T)
    ahead = x[s][:, None] > x[g][None, :]
    change = both[..., 1:] & both[..., :-1] & ahead[..., 1:] & ~ahead[..., :-1]
    return int(change.sum())


def scenario_figures(seeds: list[int]) -> dict:
    spec = load_scenario("highway_mixed_dense")
    totals = {"agent_min": 0.0, "vv": 0, "vp": 0, "pp": 0, "emergency": 0, "passes": 0, "frames": 0,
              "agent_frames": 0, "neigh": 0, "min_types": 99, "seconds": 0.0}
    scene0 = road = None
    for seed in tqdm(seeds, desc="mixed scenario", file=sys.stderr):
        t0 = time.perf_counter()
        sim = make_simulator(spec)
        frames = [sim.reset(seed)] + [sim.step() for _ in range(spec.num_frames - 1)]
        totals["seconds"] += time.perf_counter() - t0
        totals["emergency"] += sim.traffic.emergency_stops
        road = sim.road
        sim.close()
        sc = scene_from_frames(frames, spec.dt, {"scenario": spec.name})
        scene0 = scene0 or sc
        ev = collision_events(sc.xy, box_heading(sc), sc.length, sc.width, sc.valid)
        peds = (sc.agent_type[ev[:, 1]] == AgentType.PEDESTRIAN).astype(int) + \
               (sc.agent_type[ev[:, 2]] == AgentType.PEDESTRIAN).astype(int)
        totals["vv"] += int((peds == 0).sum())
        totals["vp"] += int((peds == 1).sum())
        totals["pp"] += int((peds == 2).sum())
        totals["agent_min"] += float(sc.valid.sum()) * sc.dt / 60.0
        totals["passes"] += passes(sc, SMALL, LARGE)
        totals["frames"] += sc.num_frames
        totals["agent_frames"] += int(sc.valid.sum())
        totals["neigh"] += int(neighbours_within(sc.xy, sc.valid).sum())
        totals["min_types"] = min(totals["min_types"], int((types_per_frame(sc.agent_type, sc.valid) > 0).sum(0).min()))
    per_frame = totals["agent_frames"] / totals["frames"]
    out = {
        "seeds": len(seeds), "agent_minutes": round(totals["agent_min"], 1),
        "agents_per_frame": round(per_frame, 1), "density_per_km": round(per_frame / (spec.road.length / 1000), 1),
        "agents_within_50m": round(totals["neigh"] / totals["agent_frames"], 2),
        "min_types_per_frame": totals["min_types"],
        "collisions_per_1000_agent_min": {k: round(1000 * totals[k] / totals["agent_min"], 3)
                                          for k in ("vv", "vp", "pp")},
        "collision_counts": {k: totals[k] for k in ("vv", "vp", "pp")},
        "hard_braking_agent_steps_per_1000_agent_min": round(1000 * totals["emergency"] / totals["agent_min"], 1),
        "small_passes_large_per_scene": round(totals["passes"] / len(seeds), 1),
        "sim_seconds_per_wall_second": round(len(seeds) * (spec.duration + spec.warmup) / totals["seconds"], 1),
    }
    return out, scene0, road


def plot_speed(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5), dpi=120)
    n = [r["agents"] for r in rows]
    ax.plot(n, [r["stock"] for r in rows], "o-", label="stock highway-fast-v0")
    ax.plot(n, [r["dense"] for r in rows], "s-", label="simharness HeteroHighwayEnv")
    ax.set_yscale("log")
    ax.set_xlabel("agents")
    ax.set_ylabel("agent-steps / s")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=100, help="env steps per speed measurement")
    ap.add_argument("--out", default="runs/bench/highway")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    rows = []
    for n in tqdm((20, 50, 100), desc="speed", file=sys.stderr):
        stock = stock_rate(n, args.steps)
        dense, mean_n = dense_rate(n, args.steps)
        rows.append({"agents": n, "stock": stock, "dense": dense, "dense_mean_agents": mean_n,
                     "ratio": dense / stock})
    print(f"Speed: agent-steps per second, sim {SIM_HZ} Hz, policy {POLICY_HZ} Hz, {args.steps} env steps each")
    print(f"{'agents':>7} {'stock highway-fast-v0':>22} {'HeteroHighwayEnv':>16} {'(mean agents)':>14} {'ratio':>7}")
    for r in rows:
        print(f"{r['agents']:>7} {r['stock']:>22,.0f} {r['dense']:>16,.0f} {r['dense_mean_agents']:>14.1f} "
              f"{r['ratio']:>6.1f}x")
    plot_speed(rows, out / "speed.png")

    figures, scene0, road = scenario_figures(list(range(args.seeds)))
    print(f"\nhighway_mixed_dense, {figures['seeds']} seeds x 60 s ({figures['agent_minutes']} agent-minutes)")
    for k, v in figures.items():
        print(f"  {k:36s} {v}")
    from simharness.report import plot_frame

    plot_frame(scene0, scene0.num_frames // 2, out / "frame.png", road=road)
    (out / "results.json").write_text(json.dumps({"speed": rows, "mixed_dense": figures}, indent=2))
    print(f"\nwrote {out}/speed.png, frame.png, results.json")


if __name__ == "__main__":
    main()
