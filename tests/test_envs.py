"""Gymnasium envs on the real backends: env checker, vector envs, one-libsumo-per-process, PPO."""

from __future__ import annotations

import functools
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import simharness.envs  # noqa: F401 - registers the ids

HW = {"duration": 4.0, "warmup": 8.0}
SUMO = {"duration": 4.0, "warmup": 20.0}
HW_ID, SUMO_ID = "simharness.envs:simharness/HighwayDense-v0", "simharness.envs:simharness/SumoDense-v0"


def test_highway_env_passes_the_checker_and_renders():
    env = gym.make("simharness/HighwayDense-v0", config=HW, render_mode="rgb_array")
    check_env(env.unwrapped)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    assert obs[0, -1, 0] == 1.0  # the ego is present now
    assert obs[1:, -1, 0].sum() >= 5  # dense: neighbours observed
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8
    assert len(np.unique(img.reshape(-1, 3)[::37], axis=0)) > 5  # road and coloured agents, not blank
    env.close()


def test_highway_env_reward_terms_and_truncation():
    env = gym.make("simharness/HighwayDense-v0", config={**HW, "reward": {"progress": 1.0, "accel": 0.0,
                                                                             "jerk": 0.0, "lateral": 0.0}})
    env.reset(seed=2)
    total, steps = 0.0, 0
    while True:
        _, r, term, trunc, info = env.step(np.zeros(2, np.float32))
        total += r
        steps += 1
        if term or trunc:
            break
    # Pure progress reward = metres made good; the episode lasts `duration` s at 5 Hz unless it ended.
    if not info["collided"]:
        assert total == pytest.approx(info["progress_m"], rel=1e-6, abs=1e-6)
        assert trunc and steps == 20
    assert set(info) == {"t", "speed", "progress_m", "collided", "collisions", "min_ttc", "min_gap"}
    env.close()


def test_forecast_observation_option():
    env = gym.make("simharness/HighwayDense-v0", config={**HW, "predictor": "const-vel", "num_agents": 8})
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"agents", "forecast"} and env.observation_space.contains(obs)
    assert obs["forecast"].shape == (8, 10, 3)
    present = obs["agents"][1:, -1, 0] > 0
    assert np.array_equal(obs["forecast"][:, 0, 0] > 0, present)
    # The first forecast step sits near the agent's current position (ego frame, same scale).
    assert np.allclose(obs["forecast"][present, 0, 1:], obs["agents"][1:, -1, 1:3][present], atol=0.05)
    env.close()


def test_unknown_config_key_is_refused():
    from simharness.errors import UserError

    with pytest.raises(UserError, match="unknown key 'nope'"):
        gym.make("simharness/HighwayDense-v0", config={"nope": 1})


SUMO_SCRIPT = textwrap.dedent("""
    import numpy as np
    from gymnasium.utils.env_checker import check_env
    from simharness.envs import SumoDenseEnv
    from simharness.errors import SimulatorError
    cfg = {"duration": 4.0, "warmup": 20.0}
    env = SumoDenseEnv(cfg, render_mode="rgb_array")   # built directly: a gym.make spec would make the
    check_env(env)                                      # checker open a second libsumo simulation
    img = env.render()
    assert img.ndim == 3 and len(np.unique(img.reshape(-1, 3)[::37], axis=0)) > 5
    print("CHECKED")
    other = SumoDenseEnv(cfg)
    try:
        other.reset(seed=0)
    except SimulatorError as e:
        print("SECOND:", e)
    env.close()
    other.reset(seed=0)
    print("AFTER CLOSE OK")
    other.close()
""")


def test_sumo_env_checker_and_one_simulation_per_process():
    proc = subprocess.run([sys.executable, "-c", SUMO_SCRIPT], capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "CHECKED" in proc.stdout and "AFTER CLOSE OK" in proc.stdout
    second = [line for line in proc.stdout.splitlines() if line.startswith("SECOND:")]
    assert len(second) == 1 and "one simulation per process" in second[0]


def _run_vector(vec: gym.vector.VectorEnv, steps: int = 5) -> None:
    obs, info = vec.reset(seed=[0, 1])
    assert obs.shape == (2, *vec.single_observation_space.shape)
    assert not np.array_equal(obs[0], obs[1])  # different seeds, different traffic
    for _ in range(steps):
        obs, reward, term, trunc, info = vec.step(np.zeros((2, 2), np.float32))
        assert reward.shape == (2,) and info["speed"].shape == (2,) and info["min_ttc"].shape == (2,)
    vec.close()


def test_sync_vector_env_highway():
    _run_vector(gym.vector.SyncVectorEnv([functools.partial(gym.make, HW_ID, config=HW)] * 2))


@pytest.mark.parametrize("env_id, cfg", [(HW_ID, HW), (SUMO_ID, SUMO)], ids=["highway", "sumo"])
def test_async_vector_env(env_id, cfg):
    # Each worker is its own process, so two SUMO envs run side by side.
    _run_vector(gym.vector.AsyncVectorEnv([functools.partial(gym.make, env_id, config=cfg)] * 2, context="spawn"))


def _ppo(env_id: str, cfg: dict, steps: int) -> float:
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    env = gym.make(env_id, config=cfg)
    model = PPO("MlpPolicy", env, n_steps=128, batch_size=64, n_epochs=2, seed=0, verbose=0, device="cpu")
    model.learn(total_timesteps=steps)
    assert model.num_timesteps >= steps
    obs, _ = env.reset(seed=5)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)
    env.close()
    return float(model.logger.name_to_value.get("train/value_loss", np.nan))


def test_ppo_smoke_highway():
    _ppo(HW_ID, HW, 256)


@pytest.mark.slow
@pytest.mark.parametrize("env_id, cfg", [(HW_ID, {"duration": 20.0, "warmup": 10.0}),
                                         (SUMO_ID, {"duration": 20.0, "warmup": 30.0})], ids=["highway", "sumo"])
def test_ppo_trains_some_thousand_steps(env_id, cfg):
    code = f"from tests.test_envs import _ppo; print(_ppo({env_id!r}, {cfg!r}, 3000))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
