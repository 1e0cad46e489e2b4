"""A data set folder as a replay scenario (`simharness closedloop DATA_DIR`): its defaults read off the data.

- `record_hz`: the recording's rate, or 5 Hz (the harness's usual rate) where the recording's is a whole
  multiple of it;
- `road.speed_limit`: the 95th percentile of the vehicles' recorded speeds (of all agents' where there is no
  vehicle): the ego's planner drives towards it;
- `duration`: `DEFAULT_DURATION` s, or less where the recording is shorter;
- `ego.type`: car, or pedestrian where the data set holds no vehicle;
- `replay.edge_margin`: 10 m, or 2 m where the data set holds no vehicle (pedestrian scenes span a few metres).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simharness.errors import UserError
from simharness.scenario import ScenarioSpec, parse_scenario
from simharness.scene import AgentType

DEFAULT_DURATION = 6.0  # s: short enough for the 7-17 s NGSIM scenes to offer egos, long enough to interact
DEFAULT_HZ = 5.0


def replay_scenario(path: Path, mode: str = "reactive") -> ScenarioSpec:
    """The scenario that replays the data set folder `path` (module docstring)."""
    from simharness.io.parquet import Dataset

    ds = Dataset(path)
    speeds, vehicles, dt, frames = [], False, None, 0
    for scene in ds:
        veh = scene.agent_type != int(AgentType.PEDESTRIAN)
        vehicles |= bool(veh.any())
        speeds.append((scene.speed[scene.valid & veh[:, None]], scene.speed[scene.valid]))
        dt = dt or scene.dt
        frames = max(frames, scene.num_frames)
        if scene.units != "m":
            raise UserError(f"{path}: recorded in {scene.units}, not metres; replay it from a scenario file with "
                            f"backend = \"replay\", data = \"{path}\" and replay.pixel_scale (metres per "
                            f"{scene.units})")
    if dt is None:
        raise UserError(f"{path}: the data set holds no scene to replay")
    pool = np.concatenate([s[0] if vehicles else s[1] for s in speeds])
    limit = round(float(np.ceil(10 * np.percentile(pool, 95)) / 10), 1) if pool.size else 13.9
    hz = 1.0 / dt
    if hz > DEFAULT_HZ and abs(hz / DEFAULT_HZ - round(hz / DEFAULT_HZ)) < 1e-6:
        hz = DEFAULT_HZ
    duration = min(DEFAULT_DURATION, round((frames - 1) * dt, 6))
    data = {"name": Path(path).resolve().name, "description": f"replay of the data set {path}",
            "backend": "replay", "data": str(Path(path).resolve()), "duration": duration, "warmup": 0.0,
            "record_hz": hz, "step_length": 1.0 / hz,
            "road": {"speed_limit": float(np.clip(limit, 1.0, 45.0))},
            "ego": {"enabled": True, "type": "car" if vehicles else "pedestrian", "speed": 0.0},
            "replay": {"mode": mode, "edge_margin": 10.0 if vehicles else 2.0}}
    return parse_scenario(data, str(path))
