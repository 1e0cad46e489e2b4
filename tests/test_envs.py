"""Gymnasium envs on the real backends: env checker, several SUMO envs per process, vector envs, SB3, bad input."""

from __future__ import annotations

import functools
import importlib.util
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import simharness.envs  # noqa: F401 - registers the ids
from simharness.errors import UserError

HW = {"duration": 4.0, "warmup": 8.0}
SUMO = {"duration": 4.0, "warmup": 20.0}
HW_ID, SUMO_ID = "simharness.envs:simharness/HighwayDense-v0", "simharness.envs:simharness/SumoDense-v0"


def test_highway_env_passes_both_checkers_and_renders():
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("simharness/HighwayDense-v0", config=HW, render_mode="rgb_array")
    check_env(env.unwrapped)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # SB3's checker warns on image-like or unconventional shapes
        sb3_check_env(env.unwrapped)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs) and obs.ndim == 1
    obs = obs.reshape(17, 5, -1)  # (K + 1, H, F)
    assert obs[0, -1, 0] == 1.0  # the ego is present now
    assert obs[1:, -1, 0].sum() >= 5  # dense: neighbours observed
    img = env.render()
    assert img.shape == (300, 720, 3) and img.dtype == np.uint8
    assert len(np.unique(img.reshape(-1, 3)[::37], axis=0)) > 5  # road and coloured agents, not blank
    assert (img.reshape(-1, 3) == 0).all(-1).sum() > 50  # the ego's black box (and its label) are drawn
    env.close()


def test_human_rendering_without_a_display_is_refused_in_one_line(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(UserError, match="needs a display") as err:
        gym.make("simharness/HighwayDense-v0", config=HW, render_mode="human")
    assert "\n" not in str(err.value)


def test_highway_env_reward_terms_truncation_and_step_after_the_end():
    weights = {"alive": 0.0, "progress": 1.0, "accel": 0.0, "jerk": 0.0, "lateral": 0.0, "ttc": 0.0}
    env = gym.make("simharness/HighwayDense-v0", config={**HW, "target_speed": 1000.0, "reward": weights})
    env.reset(seed=2)
    total, steps = 0.0, 0
    while True:
        _, r, term, trunc, info = env.step(np.zeros(2, np.float32))
        total += r
        steps += 1
        if term or trunc:
            break
    # Progress alone, far below its target speed: metres made good / (target m per step); 20 steps in 4 s.
    if not info["collided"]:
        assert total * 1000.0 * 0.2 == pytest.approx(info["progress_m"], rel=1e-6, abs=1e-6)
        assert trunc and steps == 20
    assert set(info) == {"t", "speed", "progress_m", "collided", "collisions", "at_fault_collisions", "on_road",
                         "min_ttc", "min_gap"}
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(2, np.float32))
    env.reset(seed=3)
    env.step(np.zeros(2, np.float32))  # a new episode steps again
    env.close()


def test_observation_matches_the_frames():
    """Row 0 is the ego at the origin heading +x; neighbours' positions are their world offsets rotated."""
    env = gym.make("simharness/HighwayDense-v0", config={**HW, "num_agents": 6, "flatten": False}).unwrapped
    obs, _ = env.reset(seed=4)
    for _ in range(3):
        obs, *_ = env.step(np.array([0.3, 0.5], np.float32))
    f = env._history.now
    e = f.ego
    assert np.allclose(obs[0, -1, :7], [1, 0, 0, f.speed[e] / 30, 0, 1, 0], atol=1e-5)
    d = np.hypot(*(f.xy - f.xy[e]).T)
    d[e] = np.inf
    near = np.argsort(d)[:6]
    c, s = np.cos(f.heading[e]), np.sin(f.heading[e])
    rel = (f.xy[near] - f.xy[e]) @ np.array([[c, -s], [s, c]])
    assert np.allclose(obs[1:, -1, 1:3], np.clip(rel / 60.0, -1, 1), atol=1e-5)
    assert np.array_equal(obs[1:, -1, 9:].argmax(-1), f.agent_type[near])
    # History: the ego's own past positions lie behind it (it drives forward).
    assert obs[0, 0, 0] == 1.0 and obs[0, 0, 1] < 0
    env.close()


def test_history_tracks_agents_by_id():
    """Agents that leave, come back, change rows or first appear (more than the initial room) are tracked by
    id over the held frames: the states of each frame where the id is present, zeros and False elsewhere."""
    from simharness.envs.observation import History
    from simharness.sim.base import Frame

    rng = np.random.default_rng(5)
    pool = np.array([f"car_{i}" for i in range(220)])
    hist, held = History(4), []
    for it in range(40):
        if it == 20:
            hist.clear()
            held = []
        n = int(rng.integers(0, 60 + 4 * it))
        ids = pool[rng.choice(60 + 4 * it, n, replace=False)] if not (it % 5 == 1 and held) else held[-1].agent_id
        f = Frame(t=0.1 * it, agent_id=ids, agent_type=np.zeros(len(ids), np.int8),
                  xy=rng.normal(size=(len(ids), 2)).astype(np.float32),
                  heading=rng.normal(size=len(ids)).astype(np.float32), speed=rng.random(len(ids)).astype(np.float32),
                  length=np.ones(len(ids), np.float32), width=np.ones(len(ids), np.float32))
        hist.append(f)
        held = (held + [f])[-4:]
        rows = rng.permutation(len(ids))[: int(rng.integers(0, len(ids) + 1))]
        xy, heading, speed, present = hist.track(rows)
        assert len(hist) == len(held) and present.shape == (rows.size, len(held))
        for j, g in enumerate(held):
            at = {a: r for r, a in enumerate(g.agent_id)}
            for i, a in enumerate(ids[rows]):
                want = np.r_[g.xy[at[a]], g.heading[at[a]], g.speed[at[a]]] if a in at else np.zeros(4)
                assert present[i, j] == (a in at)
                assert np.array_equal(np.r_[xy[i, j], heading[i, j], speed[i, j]], want.astype(np.float64))


def test_forecast_observation_option():
    env = gym.make("simharness/HighwayDense-v0", config={**HW, "predictor": "const-vel", "num_agents": 8,
                                                         "flatten": False})
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"agents", "forecast"} and env.observation_space.contains(obs)
    assert obs["forecast"].shape == (8, 10, 3)
    present = obs["agents"][1:, -1, 0] > 0
    assert np.array_equal(obs["forecast"][:, 0, 0] > 0, present)
    # The first forecast step sits near the agent's current position (ego frame, same scale).
    assert np.allclose(obs["forecast"][present, 0, 1:], obs["agents"][1:, -1, 1:3][present], atol=0.05)
    env.close()


@pytest.mark.parametrize("config, message", [
    ({"nope": 1}, "unknown key 'nope'"),
    ({"duration": float("nan")}, "key 'duration': expected a finite number"),
    ({"reward": {"progress": float("inf")}}, "key 'reward.progress': expected a finite number"),
    ({"reward": {"speed": 1.0}}, "unknown reward term 'speed'"),
    ({"obs_range": -5.0}, "key 'obs_range': expected > 0"),
    ({"num_agents": 0}, "key 'num_agents': expected an integer >= 1"),
    ({"warmup": float("-inf")}, "key 'warmup': expected a finite number"),
    ({"overrides": {"demand_scale": float("nan")}}, "key 'overrides.demand_scale'"),
    ({"action": "meta"}, "key 'action': expected one of"),
    ({"target_speed": 0.0}, "key 'target_speed': expected > 0"),
    ({"flatten": 1}, "key 'flatten': expected true or false"),
    ({"reward": {"collision": -10.0}}, "unknown reward term 'collision'"),
])
def test_bad_config_is_refused_in_one_line(config, message):
    with pytest.raises(UserError, match=message) as err:
        gym.make("simharness/HighwayDense-v0", config=config)
    assert "\n" not in str(err.value)


def test_bad_actions_are_refused_or_clipped():
    env = gym.make("simharness/HighwayDense-v0", config=HW).unwrapped
    env.reset(seed=6)
    before = env._history.now.t
    for bad in ([np.nan, 0.0], [0.0, np.inf], [-np.inf, np.nan]):
        with pytest.raises(ValueError, match="not finite"):
            env.step(np.array(bad, np.float32))
    assert env._history.now.t == before  # nothing was stepped
    with pytest.raises(ValueError, match="expected 2 values"):
        env.step(np.zeros(3, np.float32))
    # Out of range: clipped to [-1, 1] before scaling.
    assert env.command(np.array([7.0, -3.0])) == env.command(np.array([1.0, -1.0]))
    assert env.command(np.array([1.0, -1.0])).acceleration == pytest.approx(2.5)
    assert env.command(np.array([-1.0, 1.0])).acceleration == pytest.approx(-7.0)
    obs, reward, *_ = env.step(np.array([50.0, -50.0], np.float32))
    assert np.isfinite(obs).all() and np.isfinite(reward)
    env.close()


def test_discrete_meta_actions_on_both_envs():
    from simharness.envs.actions import META_ACTIONS
    from simharness.sim.base import EgoCommand

    for env_id, cfg in ((HW_ID, HW), (SUMO_ID, SUMO)):
        env = gym.make(env_id, config={**cfg, "action": "discrete"})
        check_env(env.unwrapped)
        u = env.unwrapped
        assert env.action_space == gym.spaces.Discrete(12) and len(META_ACTIONS) == 12
        assert META_ACTIONS[10] == "faster, straight" and META_ACTIONS[0] == "brake, nudge left"
        assert u.command(10).acceleration == pytest.approx(1.5) and u.command(10).lateral_velocity == 0.0
        assert u.command(7) == EgoCommand(0.0, 0.0)  # hold, straight
        assert u.command(0).acceleration == pytest.approx(-7.0) and u.command(0).lateral_velocity == pytest.approx(0.75)
        assert u.command(np.int64(5)).lateral_velocity == pytest.approx(-0.75)
        env.reset(seed=0)
        for bad in (12, -1, 2.5):
            with pytest.raises(ValueError, match="meta-action index"):
                env.step(bad)
        _, reward, *_ = env.step(8)
        assert np.isfinite(reward)
        env.close()


@pytest.mark.parametrize("env_id, cfg", [(HW_ID, {"warmup": 20.0}), (SUMO_ID, {"warmup": 30.0})],
                         ids=["highway", "sumo"])
def test_full_braking_earns_more_than_full_throttle(env_id, cfg):
    """The default reward never pays for crashing: full throttle (which runs into traffic) earns less than
    standing on the brakes over the same seeded episode."""
    env = gym.make(env_id, config=cfg)
    got = {}
    for name, action in (("brake", [-1.0, 0.0]), ("throttle", [1.0, 0.0])):
        env.reset(seed=0)
        total, done = 0.0, False
        while not done:
            _, r, term, trunc, info = env.step(np.array(action, np.float32))
            total, done = total + r, term or trunc
        got[name] = (total, info)
    assert got["throttle"][1]["at_fault_collisions"] == 1 and not got["brake"][1]["collided"]
    assert got["brake"][0] > 0 > got["throttle"][0] and got["brake"][1]["progress_m"] < 10
    env.close()


def test_collision_free_episode_outscores_any_at_fault_crash():
    """Per-step bounds of the reward: the worst collision-free episode beats the best at-fault crash, at the
    default weights and at others."""
    from simharness.envs.config import DEFAULT_CONFIG
    from simharness.envs.reward import Motion, step_reward

    steps = 100
    worst = Motion(moved=-1.0, accel=-9.0, jerk=50.0, lateral=3.0)
    best = Motion(moved=5.0, accel=0.0, jerk=0.0, lateral=0.0)
    for w in (DEFAULT_CONFIG["reward"], {**DEFAULT_CONFIG["reward"], "alive": 0.0, "jerk": -2.0},
              {**DEFAULT_CONFIG["reward"], "alive": 1.0, "progress": 3.0, "lateral": -0.5}):
        floor = min(step_reward(w, worst, 2.78, 1.5, True, None, steps, 0.0), 0.0)  # off the road a step earns 0
        top = step_reward(w, best, 2.78, 1.5, True, None, steps)
        assert top == pytest.approx(w["alive"] + w["progress"])
        assert step_reward(w, best, 2.78, 1.5, False, None, steps) == 0.0  # off the road: nothing
        crash = (steps - 1) * top + step_reward(w, best, 2.78, 1.5, True, "at_fault", steps)
        assert crash < steps * floor
        hit = step_reward(w, best, 2.78, 1.5, True, "hit", steps)
        assert step_reward(w, best, 2.78, 1.5, True, "at_fault", steps) < hit < 0


def test_closing_in_costs_before_the_contact():
    """The ttc term: nothing with nobody foreseen within 3 s, then more the sooner a contact is foreseen."""
    from simharness.envs.config import DEFAULT_CONFIG
    from simharness.envs.reward import TTC_CAP, Motion, step_reward

    w, m = DEFAULT_CONFIG["reward"], Motion(moved=1.4, accel=0.0, jerk=0.0, lateral=0.0)
    free, far, near, now = (step_reward(w, m, 1.4, 1.5, True, None, 100, t) for t in (TTC_CAP, 3.0, 1.5, 0.0))
    assert free == far == pytest.approx(w["alive"] + w["progress"])
    assert free > near > now and free - now == pytest.approx(-w["ttc"])


def test_speed_meta_actions_hold_their_speed():
    """"speed" meta-actions steer the ego's speed to their target: cruise settles at 7 m/s, stop brakes."""
    from simharness.envs.actions import SPEED_META_ACTIONS, TARGET_SPEEDS

    env = gym.make(HW_ID, config={**HW, "action": "speed", "duration": 6.0}).unwrapped
    assert env.action_space == gym.spaces.Discrete(12) and SPEED_META_ACTIONS[7] == "cruise, straight"
    env.reset(seed=0)
    v = env._history.now.speed[env._history.now.ego]
    assert env.command(1).acceleration == pytest.approx(max(-2 * v, -7.0))  # (0 - v) / 0.5 s, within max_decel
    assert env.command(5).lateral_velocity == pytest.approx(-0.75)
    speeds = []
    for _ in range(15):
        _, _, term, trunc, info = env.step(7)
        speeds.append(info["speed"])
        if term or trunc:
            break
    if not info["collided"]:
        assert abs(speeds[-1] - TARGET_SPEEDS["cruise"]) < 0.5
    env.close()


def _frame(xy, heading, speed, length=4.5, width=1.8):
    """One frame, the ego in row 0; xy (n, 2) m, heading (n,) rad, speed (n,) m/s."""
    from simharness.sim.base import Frame

    n = len(xy)
    return Frame(t=0.0, agent_id=np.array([f"a{i}" for i in range(n)]), agent_type=np.zeros(n, np.int8),
                 xy=np.asarray(xy, np.float32), heading=np.asarray(heading, np.float32),
                 speed=np.asarray(speed, np.float32), length=np.full(n, length, np.float32),
                 width=np.full(n, width, np.float32), ego=0)


def test_follow_leader_is_the_nearest_agent_in_the_corridor():
    from simharness.envs.actions import leader

    # Ahead 20 m in the corridor (gap 20 - 4.5), ahead 10 m but 3 m aside (outside it), behind, and one across.
    f = _frame([[0, 0], [20, 0.5], [10, 3.0], [-10, 0], [40, -1.0]], [0, 0, 0, 0, np.pi / 2], [8, 5, 5, 9, 1])
    gap, v = leader(f)
    assert gap == pytest.approx(15.5) and v == pytest.approx(5.0)
    # A car crossing 6 m ahead, seen side-on: its width is its extent along the ego's heading.
    f = _frame([[0, 0], [6, 0.0]], [0, np.pi / 2], [8, 1.5], length=4.5, width=1.8)
    gap, v = leader(f)
    assert gap == pytest.approx(6 - 0.9 - 2.25, abs=1e-5) and v == pytest.approx(0.0, abs=1e-6)
    assert leader(_frame([[0, 0], [-5, 0]], [0, 0], [8, 8])) == (np.inf, 0.0)


def test_follow_meta_actions_keep_the_gap_to_the_agent_ahead():
    """"follow" is "speed" with nobody ahead, brakes for a stopped car ahead, and never speeds up into one."""
    from simharness.envs.actions import action_to_command

    cfg = {"action": "follow", "max_accel": 2.5, "max_decel": 7.0, "max_lateral_speed": 1.5, "lateral": True}
    free = _frame([[0, 0]], [0], [5.0])
    speed_cfg = {**cfg, "action": "speed"}
    for i in range(12):
        assert action_to_command(i, cfg, frame=free) == action_to_command(i, speed_cfg, frame=free)
    stopped_ahead = _frame([[0, 0], [15, 0]], [0, 0], [7.0, 0.0])
    fast = action_to_command(10, cfg, frame=stopped_ahead)  # "fast, straight": 10.5 m/s wanted
    assert fast.acceleration < -2.0  # s* = 2 + 7 + 7 * 7 / (2 sqrt(2.5 * 3)) = 17.9 m > the 10.5 m gap
    assert action_to_command(10, speed_cfg, frame=stopped_ahead).acceleration == pytest.approx(2.5)
    assert action_to_command(10, cfg, frame=_frame([[0, 0], [8, 0]], [0, 0], [7.0, 0.0])).acceleration == -7.0
    held = {**cfg, "lateral": False}  # the longitudinal choices only: index 3 is "fast", the line held
    assert action_to_command(3, held, frame=stopped_ahead) == fast and fast.lateral_velocity == 0.0
    with pytest.raises(ValueError, match="0..3"):
        action_to_command(4, held, frame=stopped_ahead)
    assert gym.make(HW_ID, config={**HW, "action": "follow", "lateral": False}).action_space == gym.spaces.Discrete(4)
    env = gym.make(HW_ID, config={**HW, "action": "follow"}).unwrapped
    assert env.action_space == gym.spaces.Discrete(12)
    env.reset(seed=0)
    for _ in range(10):
        _, _, term, trunc, info = env.step(10)
        assert info["at_fault_collisions"] == 0
        if term or trunc:
            break
    env.close()


def _frames(ego_xy, ego_v, other_xy, other_v, n=9, dt=0.2):
    """n frames of an ego and one other car driving along +x at constant speeds from the given positions."""
    from simharness.sim.base import Frame

    out = []
    for i in range(n):
        t = i * dt
        xy = np.array([[ego_xy[0] + ego_v * t, ego_xy[1]], [other_xy[0] + other_v * t, other_xy[1]]], np.float32)
        out.append(Frame(t=t, agent_id=np.array(["ego", "car"]), agent_type=np.zeros(2, np.int8), xy=xy,
                         heading=np.zeros(2, np.float32), speed=np.array([ego_v, other_v], np.float32),
                         length=np.full(2, 4.5, np.float32), width=np.full(2, 1.8, np.float32), ego=0))
    return out


def test_fault_is_judged_as_the_scorecard_judges_it():
    from simharness.envs.reward import ego_fault

    # The ego at 12 m/s runs into a car at 2 m/s ahead: contact begins at the last frame, the ego's fault.
    assert ego_fault(_frames((0.0, 0.0), 12.0, (20.0, 0.0), 2.0), 0.2)
    # A car at 14 m/s runs into the back of the ego cruising at 6 m/s: the ego was hit.
    assert not ego_fault(_frames((16.5, 0.0), 6.0, (0.0, 0.0), 14.0), 0.2)


def _rollout(env: gym.Env, seed: int, steps: int = 6) -> tuple[np.ndarray, list[float]]:
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    seen, rewards = [obs], []
    for _ in range(steps):
        obs, r, term, trunc, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        seen.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return np.stack(seen), rewards


def _episodes(env: gym.Env, seed: int, episodes: int = 3) -> tuple[list[np.ndarray], list[float]]:
    """First observations and summed rewards of consecutive episodes after one seeded reset."""
    firsts, totals = [], []
    obs, _ = env.reset(seed=seed)
    for _ in range(episodes):
        firsts.append(obs)
        total, done = 0.0, False
        while not done:
            obs, r, term, trunc, _ = env.step(np.array([0.2, 0.0], np.float32))
            total += r
            done = term or trunc
        totals.append(total)
        obs, _ = env.reset()
    return firsts, totals


def test_highway_same_seed_same_rollout_across_warm_resets():
    a, b = (gym.make("simharness/HighwayDense-v0", config=HW) for _ in range(2))
    (oa, ra), (ob, rb), (oc, _) = _rollout(a, 7), _rollout(b, 7), _rollout(b, 8)
    assert np.array_equal(oa, ob) and ra == rb
    assert not np.array_equal(oa[0], oc[0])
    # reset() without a seed re-inserts the ego into the running traffic: still a function of the seed.
    (fa, ta), (fb, tb) = _episodes(a, 9), _episodes(b, 9)
    assert all(np.array_equal(x, y) for x, y in zip(fa, fb, strict=True)) and ta == tb
    assert not np.array_equal(fa[0], fa[1])  # a new episode, not a replay
    sim = a.unwrapped._sim
    assert sim.env.traffic.time > sim.env.warmup_s > 8.0  # traffic ran on from one warm-up


def test_every_reset_warms_up_when_asked():
    env = gym.make("simharness/HighwayDense-v0", config={**HW, "episodes_per_warmup": 1})
    env.reset(seed=1)
    first = env.unwrapped._sim.env.traffic
    env.reset()
    assert env.unwrapped._sim.env.traffic is not first  # a fresh warm-up
    env.close()


def test_several_sumo_envs_in_one_process():
    """gym.make twice; the checker (it builds yet another env) with rendering; same seed, same rollout."""
    first = gym.make("simharness/SumoDense-v0", config=SUMO)
    second = gym.make("simharness/SumoDense-v0", config=SUMO, render_mode="rgb_array")
    (oa, ra), (ob, rb) = _rollout(first, 3), _rollout(second, 3)
    assert np.array_equal(oa, ob) and ra == rb and len(ra) >= 3
    assert oa[-1].reshape(17, 5, -1)[1:, -1, 0].sum() >= 5  # dense: neighbours observed
    check_env(second.unwrapped)
    img = second.render()
    assert img.shape == (300, 720, 3) and len(np.unique(img.reshape(-1, 3)[::37], axis=0)) > 5  # as highway's
    other, _ = _rollout(first, 4, steps=1)
    assert not np.array_equal(other[0], oa[0])
    # Warm resets in SUMO too: the ego enters the running traffic again, identically for both.
    (fa, ta), (fb, tb) = _episodes(first, 5, 2), _episodes(second, 5, 2)
    assert all(np.array_equal(x, y) for x, y in zip(fa, fb, strict=True)) and ta == tb
    first.close()
    second.close()


def test_sync_vector_env_with_four_sumo_envs():
    vec = gym.vector.SyncVectorEnv([functools.partial(gym.make, SUMO_ID, config=SUMO)] * 4)
    obs, _ = vec.reset(seed=[0, 1, 2, 0])
    assert obs.shape == (4, *vec.single_observation_space.shape)
    assert np.array_equal(obs[0], obs[3]) and not np.array_equal(obs[0], obs[1])
    for _ in range(3):
        obs, reward, term, trunc, info = vec.step(np.tile([[0.2, -0.1]], (4, 1)).astype(np.float32))
        assert reward.shape == (4,) and info["min_ttc"].shape == (4,)
    assert np.array_equal(obs[0], obs[3])
    vec.close()


@pytest.mark.parametrize("env_id, cfg", [(HW_ID, HW), (SUMO_ID, SUMO)], ids=["highway", "sumo"])
def test_async_vector_env(env_id, cfg):
    vec = gym.vector.AsyncVectorEnv([functools.partial(gym.make, env_id, config=cfg)] * 2, context="spawn")
    obs, _ = vec.reset(seed=[0, 1])
    assert not np.array_equal(obs[0], obs[1])  # different seeds, different traffic
    for _ in range(3):
        obs, reward, *_ = vec.step(np.zeros((2, 2), np.float32))
        assert reward.shape == (2,)
    vec.close()


@pytest.mark.parametrize("vec", ["dummy", "subproc"])
def test_sb3_make_vec_env_with_four_sumo_envs(vec):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    cls = DummyVecEnv if vec == "dummy" else SubprocVecEnv
    venv = make_vec_env(SUMO_ID, n_envs=4, seed=0, vec_env_cls=cls, env_kwargs={"config": SUMO})
    obs = venv.reset()
    assert obs.shape == (4, *venv.observation_space.shape)
    assert not np.array_equal(obs[0], obs[1])  # make_vec_env seeds 0..3
    dones = np.zeros(4, bool)
    for _ in range(22):  # past the 20-step episode: the vec env resets itself
        obs, reward, done, info = venv.step(np.zeros((4, 2), np.float32))
        dones |= done
        assert np.isfinite(obs).all() and np.isfinite(reward).all()
    assert dones.all()
    venv.close()


def test_sb3_ppo_with_eval_callback_on_sumo():
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.monitor import Monitor

    torch.set_num_threads(1)
    venv = make_vec_env(SUMO_ID, n_envs=2, seed=0, env_kwargs={"config": SUMO})
    eval_env = Monitor(gym.make(SUMO_ID, config=SUMO))  # a third SUMO env in this process
    callback = EvalCallback(eval_env, eval_freq=16, n_eval_episodes=1, verbose=0)
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=16, n_epochs=1, seed=0, verbose=0, device="cpu")
    model.learn(total_timesteps=32, callback=callback)
    assert callback.n_calls == 16 and np.isfinite(callback.last_mean_reward)  # evaluated once, a full episode
    venv.close()
    eval_env.close()


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


def test_reward_gap_is_safety_min_gap_bit_for_bit():
    """The compiled per-component gaps give the float32 values of `safety.min_gap`, and the reward's ego gap
    their minimum (random poses, rounded positions and zero headings included: the cases where a different
    order of operations would show)."""
    from simharness.envs.reward import GAP_CAP, ego_safety
    from simharness.metrics import safety
    from simharness.metrics.separating_axis import gaps
    from simharness.sim.base import Frame

    rng = np.random.default_rng(0)
    for it in range(300):
        n = int(rng.integers(2, 30))
        xy = rng.uniform(-30, 30, (n, 2)).astype(np.float32).astype(np.float64)
        if it % 3 == 0:
            xy = np.round(xy, 1).astype(np.float32).astype(np.float64)  # (a Frame holds float32)
        heading = rng.uniform(-np.pi, np.pi, n).astype(np.float32).astype(np.float64)
        heading[rng.random(n) < 0.4] = 0.0
        length = rng.choice([0.5, 1.8, 4.5, 12.0], n).astype(np.float32).astype(np.float64)
        width = rng.choice([0.5, 0.8, 1.8, 2.5], n).astype(np.float32).astype(np.float64)
        e = int(rng.integers(n))
        rows = np.flatnonzero(np.arange(n) != e)
        sub = np.concatenate([[e], rows])
        ref = safety.min_gap(xy[sub][:, None], heading[sub][:, None], length[sub], width[sub],
                             np.ones((sub.size, 1), bool), 0)[1:, 0]
        h = np.concatenate([heading, heading + np.pi / 2])  # each box's forward and left directions
        c, s = np.cos(h), np.sin(h)
        got = gaps(xy[e] - xy[rows], c[:n], s[:n], c[n:], s[n:], length, width, e, rows)
        assert got.dtype == np.float32 and np.array_equal(got.view(np.int32), ref.view(np.int32))
        frame = Frame(t=0.0, agent_id=np.array([f"a{i}" for i in range(n)]), agent_type=np.zeros(n, np.int8),
                      xy=xy.astype(np.float32), heading=heading.astype(np.float32),
                      speed=np.zeros(n, np.float32), length=length.astype(np.float32),
                      width=width.astype(np.float32), ego=e)
        assert ego_safety(frame).gap == min(float(ref.min()), GAP_CAP)


def test_speed_bench_compares_two_checkouts_in_turn(tmp_path):
    """bench/envs.py --against: both checkouts' envs step in worker processes; a directory without simharness is
    refused rather than measured with the installed one."""
    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("envs_bench", root / "bench" / "envs.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rec = bench.compare(root, 4, 2, ("HighwayDense-v0",))["HighwayDense-v0"]
    assert rec["ratio"] > 0 and rec["this_steps_per_s"] > 0 and rec["other_steps_per_s"] > 0
    assert rec["this_sim_us_per_step"] > 0 and np.isfinite(rec["other_layer_us_per_step"])
    with pytest.raises(SystemExit, match="imported simharness from"):
        bench.compare(tmp_path, 4, 2, ("HighwayDense-v0",))
