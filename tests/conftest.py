"""Shared test fixtures. Tests use the real simulators and real files; nothing is mocked."""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pytest

# Two cores are shared by xdist workers: keep torch and BLAS from oversubscribing.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
# Window caches of the tests go to a throw-away folder, not the user's ~/.cache.
os.environ.setdefault("SIMHARNESS_CACHE_DIR", tempfile.mkdtemp(prefix="simharness-test-cache-"))

from simharness.scene import AgentType, Scene  # noqa: E402


def make_scene(num_agents: int = 3, num_frames: int = 10, dt: float = 0.2, seed: int = 0) -> Scene:
    """A small synthetic scene: agents on straight lines with some invalid frames."""
    rng = np.random.default_rng(seed)
    t = np.arange(num_frames) * dt
    v = rng.uniform(2, 10, (num_agents, 1))
    y0 = rng.uniform(-5, 5, (num_agents, 1))
    xy = np.stack([rng.uniform(0, 50, (num_agents, 1)) + v * t, y0 + 0 * t], -1)
    valid = np.ones((num_agents, num_frames), bool)
    valid[0, :2] = False
    return Scene(
        xy=xy, heading=np.zeros((num_agents, num_frames)), speed=np.repeat(v, num_frames, 1), valid=valid,
        agent_id=[f"a{i}" for i in range(num_agents)],
        agent_type=[AgentType(i % len(AgentType)) for i in range(num_agents)],
        length=np.full(num_agents, 4.0), width=np.full(num_agents, 2.0), dt=dt, ego=1,
        meta={"source": "test"},
    )


@pytest.fixture
def scene() -> Scene:
    return make_scene()
