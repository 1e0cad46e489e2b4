"""PolicyPlanner: the env's own observation and action mapping, driving the ego in the real closed loop."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import simharness.envs  # noqa: F401
from simharness.closedloop import LoopConfig, prepare_spec, simulate
from simharness.errors import UserError
from simharness.policy_planner import PolicyPlanner, load_policy_planner
from simharness.scenario import load_scenario
from simharness.scene import Scene


class Recorder:
    """A fixed-action policy that keeps what it was shown (SB3's predict signature)."""

    def __init__(self, action: tuple[float, float]) -> None:
        self.action = np.asarray(action, np.float32)
        self.seen: list[np.ndarray] = []

    def predict(self, observation, state=None, episode_start=None, deterministic=False):  # noqa: ANN001
        self.seen.append(observation)
        return self.action, None


def _now(frame) -> Scene:  # noqa: ANN001 - what the loop hands a planner: the frame as a one-column Scene
    return Scene(xy=frame.xy[:, None], heading=frame.heading[:, None], speed=frame.speed[:, None],
                 valid=np.ones((frame.num_agents, 1), bool), agent_id=frame.agent_id, agent_type=frame.agent_type,
                 length=frame.length, width=frame.width, dt=0.2, ego=frame.ego)


def test_planner_sees_the_env_observation_and_maps_actions_like_the_env():
    env = gym.make("simharness/HighwayDense-v0", config={"duration": 4.0, "warmup": 8.0}).unwrapped
    obs, _ = env.reset(seed=3)
    policy = Recorder((0.5, -2.0))
    planner = PolicyPlanner(policy)
    for frame in env._history.frames:  # the env's reset frames: H of them, the ego in each
        command = planner.plan(_now(frame), None)
    assert np.array_equal(policy.seen[-1], obs)
    assert command == env.command(np.array([0.5, -2.0]))  # clipped to -1, scaled like the env
    for _ in range(3):
        obs, *_ = env.step(np.array([0.5, -1.0], np.float32))
        planner.plan(_now(env._history.now), None)
        assert np.array_equal(policy.seen[-1], obs)
    planner.reset()
    assert planner.plan(_now(env._history.now), None) is None  # no history yet: the simulator drives
    env.close()


def test_speed_meta_actions_steer_from_the_ego_s_speed_like_the_env():
    env = gym.make("simharness/HighwayDense-v0", config={"duration": 4.0, "warmup": 8.0, "action": "speed"}).unwrapped
    env.reset(seed=3)
    policy = Recorder((0.0, 0.0))
    policy.action = np.int64(1)  # "stop, straight": brakes from the ego's speed now
    planner = PolicyPlanner(policy, {"action": "speed"})
    for frame in env._history.frames:
        command = planner.plan(_now(frame), None)
    assert command == env.command(1) and command.acceleration < -1.0
    env.close()


def test_follow_meta_actions_keep_the_gap_like_the_env():
    cfg = {"action": "follow", "lateral": False}
    env = gym.make("simharness/HighwayDense-v0", config={"duration": 4.0, "warmup": 8.0, **cfg}).unwrapped
    env.reset(seed=3)
    policy = Recorder((0.0, 0.0))
    policy.action = np.int64(3)  # "fast", the line held
    planner = PolicyPlanner(policy, cfg)
    for frame in env._history.frames:
        command = planner.plan(_now(frame), None)
    assert command == env.command(3) and command.lateral_velocity == 0.0
    env.close()


def test_forecast_observation_matches_the_env():
    cfg = {"duration": 4.0, "warmup": 8.0, "predictor": "const-vel", "num_agents": 8}
    env = gym.make("simharness/HighwayDense-v0", config=cfg).unwrapped
    obs, _ = env.reset(seed=3)
    policy = Recorder((0.0, 0.0))
    planner = PolicyPlanner(policy, {k: v for k, v in cfg.items() if k not in ("duration", "warmup")})
    for frame in env._history.frames:
        planner.plan(_now(frame), None)
    assert set(policy.seen[-1]) == {"agents", "forecast"}
    assert all(np.array_equal(policy.seen[-1][k], obs[k]) for k in obs)
    env.close()


def test_sb3_policies_drive_the_closed_loop_loaded_without_unpickling(tmp_path):
    import json
    import zipfile

    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    env = gym.make("simharness/HighwayDense-v0", config={"duration": 4.0, "warmup": 8.0, "action": "discrete"})
    PPO("MlpPolicy", env, n_steps=64, seed=0, device="cpu").save(tmp_path / "p.zip")
    env.close()
    # Garble every pickled field: the loader must rebuild them, never unpickle what the file holds.
    with zipfile.ZipFile(tmp_path / "p.zip") as z:
        files = {n: z.read(n) for n in z.namelist()}
    data = json.loads(files["data"])
    for value in data.values():
        if isinstance(value, dict) and ":serialized:" in value:
            value[":serialized:"] = "not a pickle"
    files["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(tmp_path / "garbled.zip", "w") as z:
        for name, blob in files.items():
            z.writestr(name, blob)
    spec = prepare_spec(load_scenario("highway_mixed_dense").with_overrides({"duration": 4.0, "warmup": 8.0}))
    planner = load_policy_planner(tmp_path / "garbled.zip")  # no JSON note: the config comes from its spaces
    assert planner.config["action"] == "discrete"
    scene, _, _, timing = simulate(spec, 0, None, planner, LoopConfig())
    e = scene.ego
    assert e >= 0 and scene.valid[e].sum() >= 15 and timing["plan"] > 0
    with pytest.raises(UserError, match="no such file"):
        load_policy_planner(tmp_path / "missing.zip")
    (tmp_path / "bad.zip").write_bytes(b"not a zip")
    with pytest.raises(UserError, match="not a stable-baselines3 model"):
        load_policy_planner(tmp_path / "bad.zip")
    with pytest.raises(UserError, match="observation_space has shape"):
        load_policy_planner(tmp_path / "p.zip", {"action": "discrete", "num_agents": 4})
    with pytest.raises(UserError, match="action_space has 12 actions"):
        load_policy_planner(tmp_path / "p.zip", {"action": "follow", "lateral": False})


def test_a_line_held_policy_loads_without_a_note(tmp_path):
    from stable_baselines3 import PPO

    env = gym.make("simharness/HighwayDense-v0", config={"duration": 4.0, "warmup": 8.0, "action": "follow",
                                                          "lateral": False})
    PPO("MlpPolicy", env, n_steps=64, seed=0, device="cpu").save(tmp_path / "p.zip")
    env.close()
    planner = load_policy_planner(tmp_path / "p.zip")  # Discrete(4): the longitudinal choices, the line held
    assert planner.config["lateral"] is False and planner.policy.action_space.n == 4


def test_the_episode_ends_at_the_policy_s_collision():
    """Full throttle into dense traffic: the loop stops at the first contact, as the env does, and the
    shorter Scene is scored like any other."""
    from simharness.closedloop import score_episode

    spec = prepare_spec(load_scenario("highway_mixed_dense").with_overrides({"duration": 30.0, "warmup": 20.0}))
    planner = PolicyPlanner(Recorder((1.0, 0.0)))
    scene, issued, _, _ = simulate(spec, 0, None, planner, LoopConfig())
    assert planner.ended and scene.num_frames < spec.num_frames
    scores = score_episode(scene, issued, LoopConfig())
    assert scores["collided"] == 1.0 and scores["first_collision_t"] == pytest.approx(scene.times[-1])


def test_the_shipped_policy_loads_with_its_note():
    import json

    from simharness.policy_planner import SHIPPED

    note = json.loads(SHIPPED.with_suffix(".json").read_text())
    assert note["trained_steps"] > 0 and "command" in note and SHIPPED.stat().st_size < 5_000_000
    planner = load_policy_planner("ppo")
    config = {k: v for k, v in note["env_config"].items() if k not in ("duration", "warmup")}
    env = gym.make("simharness/HighwayDense-v0", config={**config, "duration": 4.0, "warmup": 8.0}).unwrapped
    obs, _ = env.reset(seed=0)
    action, _ = planner.policy.predict(obs, deterministic=True)
    assert env.action_space.contains(action)
    env.close()


def test_the_fixed_cruise_example_drives_as_a_planner_plug_in():
    from pathlib import Path

    from simharness.plugins import load_planner

    path = Path(__file__).resolve().parents[1] / "examples" / "cruise_policy.py"
    spec = prepare_spec(load_scenario("highway_mixed_dense").with_overrides({"duration": 6.0, "warmup": 8.0}))
    planner = load_planner(f"{path}:Cruise", spec)
    assert isinstance(planner, PolicyPlanner) and planner.config["action"] == "follow"
    scene, issued, _, _ = simulate(spec, 0, None, planner, LoopConfig())
    e = scene.ego
    assert e >= 0 and scene.valid[e].sum() >= 25 and not planner.ended
    assert issued  # the policy, not the simulator, drove once the ego had its history
