"""Plug-ins: a user's predictor or planner named as file.py:NAME, module:NAME or an installed entry point, through
the loader (`simharness.plugins`) and the command line (real highway backend, real worker processes)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import make_scene

from simharness.errors import UserError
from simharness.plugins import check_predictor, label, load_planner, load_predictor, predictor_names
from simharness.scene import Predictor

SIMHARNESS = [sys.executable, "-m", "simharness"]
REPO = Path(__file__).resolve().parents[1]

PLUGIN = '''
import numpy as np

from predictor.models.const_vel import ConstantVelocity
from simharness.scene import Forecast


class Still:
    """Everyone stays where they are now."""

    def predict(self, history, targets, horizon):
        xy = history.xy[targets, -1]
        return Forecast(agent_id=history.agent_id[targets], mean=np.repeat(xy[:, None], horizon, 1), dt=history.dt)


def make_cv():
    return ConstantVelocity(2)


INSTANCE = Still()
NUMBER = 3


def make_number():
    return 3


class NeedsArgs:
    def __init__(self, weights):
        self.weights = weights

    def predict(self, history, targets, horizon):
        raise AssertionError


class Hold:
    """A planner: hold speed and line (the simulator's command None would hand the ego back)."""

    def plan(self, now, forecast):
        from simharness.sim.base import EgoCommand

        return EgoCommand(acceleration=0.0, lateral_velocity=0.0)
'''

NO_GUARD = '''
import os
from pathlib import Path

from predictor.models.const_vel import ConstantVelocity

# top-level code and no `if __name__ == "__main__":` guard: it runs wherever the file is imported
assert __name__ not in ("__main__", "__mp_main__"), __name__
with Path(os.environ["PLUGIN_LOG"]).open("a") as log:
    log.write(f"{os.getpid()} {__name__}\\n")
print("plug-in loaded")
CV = ConstantVelocity()
'''


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def run_cli(*args: str, cwd: Path | None = None, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*SIMHARNESS, *args], capture_output=True, text=True, cwd=cwd, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})})


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """A small highway data set: one 12 s scene of the dense mix."""
    out = tmp_path_factory.mktemp("plugins") / "ds"
    r = run_cli("generate", "highway_mixed_dense", "--seeds", "0", "--duration", "12", "--out", str(out),
                "--workers", "1")
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def short(tmp_path_factory) -> Path:
    """stress/cut_in cut to 5 s of driving after a 5 s warm-up (its first cut-in comes at 2.5 s)."""
    from simharness.scenario import SCENARIO_DIR

    text = (SCENARIO_DIR / "stress" / "cut_in.toml").read_text()
    text = text.replace("\nduration = 15.0\n", "\nduration = 5.0\n").replace("\nwarmup = 20.0\n", "\nwarmup = 5.0\n")
    out = tmp_path_factory.mktemp("plugins") / "cut_in_short.toml"
    out.write_text(text)
    return out


# ---------------------------------------------------------------------- the loader
def test_file_plugin_instance_class_and_factory(tmp_path):
    f = write(tmp_path / "mine.py", PLUGIN)
    scene = make_scene(4, 12)
    targets = np.array([1, 2, 3])
    for name in ("INSTANCE", "Still"):  # an instance, a class (constructed with no arguments)
        p = load_predictor(f"{f}:{name}")
        fc = p.predict(scene, targets, 5)
        assert isinstance(p, Predictor) and fc.mean.shape == (3, 5, 2)
        assert np.allclose(fc.mean, scene.xy[targets, -1][:, None])
    cv = load_predictor(f"{f}:make_cv")  # a zero-argument factory
    assert cv.name == "const-vel:2"
    reference = load_predictor("const-vel:2").predict(scene, targets, 5)
    assert np.allclose(cv.predict(scene, targets, 5).mean, reference.mean)
    # imported once per process, under a private name (never __main__)
    assert type(load_predictor(f"{f}:Still")) is type(load_predictor(f"{f}:INSTANCE"))
    assert type(load_predictor(f"{f}:Still")).__module__.startswith("_simharness_plugin_mine_")
    assert label(f"{f}:Still") == "mine:Still" and label("const-vel") == "const-vel"


def test_module_plugin(tmp_path, monkeypatch):
    write(tmp_path / "my_models_pkg.py", PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    p = load_predictor("my_models_pkg:make_cv")
    assert p.name == "const-vel:2"


def test_entry_point(tmp_path, monkeypatch):
    """An installed distribution registers `plug-cv` in the group simharness.predictors."""
    write(tmp_path / "sh_plug_demo.py", PLUGIN)
    info = tmp_path / "sh_plug_demo-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: sh-plug-demo\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[simharness.predictors]\nplug-cv = sh_plug_demo:make_cv\n"
                                           "plug-broken = sh_plug_demo:NeedsArgs\n"
                                           "[simharness.planners]\nplug-hold = sh_plug_demo:Hold\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert load_predictor("plug-cv").name == "const-vel:2"
    assert "plug-cv" in predictor_names()
    with pytest.raises(UserError, match=r"predictor plug-in 'plug-broken': constructing it with no arguments failed"):
        load_predictor("plug-broken")
    from simharness.scenario import load_scenario

    assert type(load_planner("plug-hold", load_scenario("stress/cut_in"))).__name__ == "Hold"


@pytest.mark.parametrize(("attr", "why"), [
    ("Nope", "has no attribute 'Nope'"),
    ("NUMBER", "got int, expected a Predictor"),
    ("make_number", "got int, expected a Predictor"),
    ("NeedsArgs", "constructing it with no arguments failed: TypeError"),
    ("Hold", "got Hold, expected a Predictor"),
])
def test_bad_plugin_is_one_line(tmp_path, attr, why):
    f = write(tmp_path / "mine.py", PLUGIN)
    with pytest.raises(UserError, match=why) as e:
        load_predictor(f"{f}:{attr}")
    assert f"{f}:{attr}" in str(e.value) and "\n" not in str(e.value)


def test_broken_files_and_unknown_names(tmp_path):
    broken = write(tmp_path / "broken.py", "import numpy\nraise RuntimeError('weights missing')\n")
    with pytest.raises(UserError, match=r"importing .*broken.py failed: RuntimeError: weights missing"):
        load_predictor(f"{broken}:X")
    syntax = write(tmp_path / "syntax.py", "def f(:\n")
    with pytest.raises(UserError, match="SyntaxError"):
        load_predictor(f"{syntax}:X")
    with pytest.raises(UserError, match="no such file"):
        load_predictor(f"{tmp_path}/absent.py:X")
    with pytest.raises(UserError, match="importing module no_such_module_here failed: ModuleNotFoundError"):
        load_predictor("no_such_module_here:X")
    with pytest.raises(UserError) as e:
        check_predictor("mymodel", references=("oracle", "static", "none"))
    for name in ("const-vel", "traphic", "oracle", "static", "none", "FILE.py:NAME", "MODULE:NAME"):
        assert name in str(e.value)
    check_predictor("oracle", references=("oracle",))  # a reference ego is the caller's to handle


def test_planners(tmp_path):
    from simharness.pdm_planner import PDMPlanner
    from simharness.planners import SamplingPlanner
    from simharness.scenario import load_scenario

    spec = load_scenario("stress/cut_in")
    f = write(tmp_path / "mine.py", PLUGIN)
    assert isinstance(load_planner("pdm", spec), PDMPlanner)
    assert isinstance(load_planner("sampling", spec), SamplingPlanner)
    assert type(load_planner(f"{f}:Hold", spec)).__name__ == "Hold"
    with pytest.raises(UserError, match="got Still, expected a Planner"):
        load_planner(f"{f}:Still", spec)
    with pytest.raises(UserError, match="unknown planner 'fancy'; expected one of pdm, sampling, ppo"):
        load_planner("fancy", spec)
    with pytest.raises(UserError, match="no such file"):
        load_planner(str(tmp_path / "policy.zip"), spec)


def test_env_predictor_plugin(tmp_path):
    """The gym env's "predictor" config takes a plug-in: the same forecast observation as the built-in it wraps."""
    import gymnasium as gym

    import simharness.envs  # noqa: F401  # registers the envs

    f = write(tmp_path / "mine.py", PLUGIN)
    obs = []
    for name in (f"{f}:make_cv", "const-vel:2"):
        env = gym.make("simharness/HighwayDense-v0", config={"duration": 4.0, "warmup": 8.0, "predictor": name})
        obs.append(env.reset(seed=0)[0])
        env.close()
    assert obs[0].keys() == obs[1].keys() and "forecast" in obs[0]
    assert all(np.array_equal(obs[0][k], obs[1][k]) for k in obs[0])


def test_ppo_planner_and_policy_zip():
    from simharness.policy_planner import SHIPPED, PolicyPlanner
    from simharness.scenario import load_scenario

    spec = load_scenario("stress/cut_in")
    assert isinstance(load_planner("ppo", spec), PolicyPlanner)
    assert isinstance(load_planner(str(SHIPPED), spec), PolicyPlanner)


# ---------------------------------------------------------------------- the command line
def test_evaluate_file_plugin_cli(tmp_path, data):
    f = write(tmp_path / "mine.py", PLUGIN)
    r = run_cli("evaluate", "--data", str(data), "--model", f"{f}:make_cv", "--split", "all", "--out",
                str(tmp_path / "ev"))
    assert r.returncode == 0, r.stderr
    mine = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    r = run_cli("evaluate", "--data", str(data), "--model", "const-vel:2", "--split", "all", "--out",
                str(tmp_path / "cv"))
    assert r.returncode == 0, r.stderr
    ref = json.loads((tmp_path / "cv" / "metrics.json").read_text())
    assert mine["samples"] == ref["samples"] > 0 and mine["ade"] == pytest.approx(ref["ade"])


def test_module_plugin_cli_from_the_current_folder(tmp_path, data):
    write(tmp_path / "my_models.py", PLUGIN)
    r = run_cli("evaluate", "--data", str(data), "--model", "my_models:Still", "--split", "all", "--out",
                str(tmp_path / "ev"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "ev" / "metrics.json").read_text())["ade"] > 0


def test_plugin_without_main_guard_through_two_workers(tmp_path, short):
    """Workers import the plug-in file by path under a private name: its unguarded top-level code runs once per
    process and never as __main__, and both episodes complete."""
    f = write(tmp_path / "noguard.py", NO_GUARD)
    log = tmp_path / "imports.log"
    r = run_cli("closedloop", str(short), "--predictor", f"{f}:CV", "--seeds", "0-1", "--workers", "2",
                "--out", str(tmp_path / "cl"), env={"PLUGIN_LOG": str(log)})
    assert r.returncode == 0, r.stderr
    scores = json.loads((tmp_path / "cl" / "scores.json").read_text())
    assert scores["episodes"] == 2 and scores["predictor"] == f"{f}:CV"
    pids, names = zip(*(line.split() for line in log.read_text().splitlines()), strict=True)
    assert len(set(pids)) == 3  # the parent's fail-fast check and one per worker
    assert all(n.startswith("_simharness_plugin_noguard_") for n in names)


def test_planner_plugin_cli(tmp_path, short):
    f = write(tmp_path / "mine.py", PLUGIN)
    r = run_cli("closedloop", str(short), "--predictor", "const-vel", "--planner", f"{f}:Hold", "--seeds", "0",
                "--workers", "1", "--out", str(tmp_path / "cl"))
    assert r.returncode == 0, r.stderr
    ep = json.loads((tmp_path / "cl" / "scores.json").read_text())["per_episode"][0]
    assert ep["planner"] == f"{f}:Hold" and ep["ego_present"]


@pytest.mark.parametrize("command", ["closedloop", "sensitivity", "evaluate"])
def test_broken_plugin_cli_is_one_line_exit_2(tmp_path, data, command):
    broken = write(tmp_path / "broken.py", "raise RuntimeError('weights missing')\n")
    spec = f"{broken}:Model"
    args = {"closedloop": ["closedloop", "stress/cut_in", "--predictor", spec, "--seeds", "0-3", "--workers", "2"],
            "sensitivity": ["sensitivity", "stress/cut_in", "--predictor", spec, "--perturb", "noise=0,1"],
            "evaluate": ["evaluate", "--data", str(data), "--model", spec]}[command]
    r = run_cli(*args, "--out", str(tmp_path / "out"))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"simharness: error: predictor plug-in {spec!r}: importing {broken} "
                                             "failed: RuntimeError: weights missing"]
