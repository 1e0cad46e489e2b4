"""Imitation of the prediction-driven planner (bench/train_imitation.py): labels invert the env's action map, a
labelled closed-loop episode records the expert's commands, and a fitted policy loads and drives."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from simharness.envs.actions import action_to_command, command_to_action
from simharness.envs.config import DEFAULT_CONFIG, resolve_config
from simharness.sim.base import EgoCommand

ROOT = Path(__file__).resolve().parents[1]


def _script():  # noqa: ANN202 - the bench script as a module
    spec = importlib.util.spec_from_file_location("train_imitation", ROOT / "bench" / "train_imitation.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _config(**given) -> dict:  # noqa: ANN003
    return resolve_config(DEFAULT_CONFIG, {"scenario": "highway_mixed_dense", **given}, "test")


def test_command_to_action_inverts_the_env_action_map():
    config = _config()
    rng = np.random.default_rng(0)
    for acc, lat in zip(rng.uniform(-7.0, 2.5, 200), rng.uniform(-1.5, 1.5, 200), strict=True):
        action = command_to_action(EgoCommand(acc, lat), config)
        back = action_to_command(action, config)
        assert action.dtype == np.float32 and np.all(np.abs(action) <= 1.0)
        assert back.acceleration == pytest.approx(acc, abs=1e-5)
        assert back.lateral_velocity == pytest.approx(lat, abs=1e-5)
    # beyond the limits: clipped to them
    assert command_to_action(EgoCommand(-20.0, 3.0), config).tolist() == [-1.0, 1.0]
    assert command_to_action(EgoCommand(9.0, -3.0), config).tolist() == [1.0, -1.0]


def test_expert_episode_labels_are_the_commands_it_drove():
    m = _script()
    job = {"scenario": "highway_mixed_dense", "seed": 1, "duration": 4.0, "config": _config(), "student": None,
           "beta": 1.0}
    driven: list[EgoCommand] = []
    plan = m.LabellingPlanner.plan

    def recording(self, now, forecast):  # noqa: ANN001, ANN202
        command = plan(self, now, forecast)
        driven.append(command)
        return command

    m.LabellingPlanner.plan = recording
    try:
        out = m.rollout(job)
    finally:
        m.LabellingPlanner.plan = plan
    h = DEFAULT_CONFIG["history_frames"]
    assert len(out["obs"]) == len(out["act"]) == len(driven) - (h - 1)  # labelled once the ego has H frames
    assert out["obs"][0].shape == (17 * h * 18,)
    back = [action_to_command(a, job["config"]) for a in out["act"]]
    for got, want in zip(back, driven[h - 1:], strict=True):
        assert got.acceleration == pytest.approx(np.clip(want.acceleration, -7.0, 2.5), abs=1e-4)
        assert got.lateral_velocity == pytest.approx(np.clip(want.lateral_velocity, -1.5, 1.5), abs=1e-4)
    assert not out["collided"] and out["progress_m"] > 5.0


def test_fitted_policy_matches_its_labels_and_loads_as_a_planner(tmp_path):
    from simharness.closedloop import LoopConfig, prepare_spec, simulate
    from simharness.policy_planner import load_policy_planner
    from simharness.scenario import load_scenario

    m = _script()
    config = _config()
    model = m.make_model(config, seed=0)
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (512, 17 * 5 * 18)).astype(np.float32)
    act = np.clip(obs[:, :2] * 0.8, -1, 1)  # a learnable map: the first two features, scaled
    before = m.fit(model, obs, act, epochs=1, lr=1e-3, batch=128, seed=0)
    after = m.fit(model, obs, act, epochs=40, lr=1e-3, batch=128, seed=0)
    assert after < 0.2 * before
    path = tmp_path / "policy.zip"
    m.save(model, path, {"env_config": config})
    planner = load_policy_planner(path)
    got, _ = planner.policy.predict(obs[:8], deterministic=True)
    np.testing.assert_allclose(got, act[:8], atol=0.15)
    spec = prepare_spec(load_scenario("highway_mixed_dense").with_overrides({"duration": 3.0}))
    scene, *_ = simulate(spec, 2, None, planner, LoopConfig())
    assert scene.num_frames > 5 and scene.ego >= 0


@pytest.mark.slow
def test_the_script_writes_a_policy_the_closed_loop_loads(tmp_path):
    import json
    import subprocess
    import sys

    from simharness.policy_planner import PolicyPlanner, load_policy_planner

    run = tmp_path / "run"
    subprocess.run([sys.executable, str(ROOT / "bench" / "train_imitation.py"), "--episodes", "1", "--iterations", "1",
                    "--duration", "6", "--epochs", "2", "--workers", "1", "--run", str(run)], check=True, cwd=ROOT,
                   capture_output=True)
    note = json.loads((run / "policy.json").read_text())
    assert [r["iteration"] for r in note["iterations"]] == [0, 1] and note["samples"] == note["trained_steps"] > 0
    assert note["cpu_s"] > 0 and (run / "iteration0.zip").is_file()
    assert isinstance(load_policy_planner(run / "policy.zip"), PolicyPlanner)
