"""Scenario files: a mistake gives one line naming file, key and what was expected; exit 2; nothing written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from simharness.errors import UserError
from simharness.scenario import load_scenario

GOOD = """\
name = "unit"
backend = "sumo"
duration = 5.0
warmup = 0.0
[road]
layout = "arterial"
length = 200.0
[demand]
car = 600
motorcycle = 400
[pedestrians]
crossing_rate = 60
"""

# (what to change, text fragments the one-line message must hold)
BAD = {
    "unknown key": (GOOD.replace("duration = 5.0", "durration = 5.0"), ["key 'durration'", "unknown key"]),
    "unknown nested key": (GOOD.replace("length = 200.0", "lenght = 200.0"), ["key 'road.lenght'", "unknown key"]),
    "wrong type": (GOOD.replace("duration = 5.0", 'duration = "long"'), ["key 'duration'", "expected a number"]),
    "negative rate": (GOOD.replace("car = 600", "car = -600"), ["key 'demand.car'", "expected a number in"]),
    "negative pedestrian rate": (GOOD.replace("crossing_rate = 60", "crossing_rate = -1"),
                                 ["key 'pedestrians.crossing_rate'", "expected a number in"]),
    "unknown agent type": (GOOD.replace("car = 600", "tuktuk = 600"), ["key 'demand.tuktuk'", "unknown agent type"]),
    "bad layout": (GOOD.replace('layout = "arterial"', 'layout = "roundabout"'), ["key 'road.layout'", "one of"]),
    "not toml": (GOOD + "[road\n", ["not valid TOML"]),
    "all-zero demand": (GOOD.replace("car = 600", "car = 0").replace("motorcycle = 400", "motorcycle = 0")
                        .replace("crossing_rate = 60", "crossing_rate = 0"), ["key 'demand'", "no agents at all"]),
    "zero demand_scale": (GOOD.replace('backend = "sumo"', 'backend = "sumo"\ndemand_scale = 0'),
                          ["key 'demand'", "demand_scale = 0"]),
    "nested 100,000 deep": ("x = " + "[" * 100_000 + "]" * 100_000 + "\n", ["nested too deeply"]),
    "a megabyte and more": (GOOD + "#" * (1 << 20) + "\n", ["bytes; a scenario file is at most"]),
}


def run_cli(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simharness", *argv], capture_output=True, text=True, cwd=cwd)


def test_good_file_loads(tmp_path: Path) -> None:
    (tmp_path / "unit.toml").write_text(GOOD)
    spec = load_scenario(tmp_path / "unit.toml")
    assert spec.duration == 5.0 and spec.flows()
    assert spec.config_hash() == load_scenario(tmp_path / "unit.toml").config_hash()
    assert spec.with_overrides({"duration": 6.0}).config_hash() != spec.config_hash()


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_file_is_one_line_naming_file_and_key(tmp_path: Path, case: str) -> None:
    text, fragments = BAD[case]
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(UserError) as err:
        load_scenario(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message
    for fragment in fragments:
        assert fragment in message, message


@pytest.mark.parametrize("case", ["unknown key", "negative rate", "unknown agent type", "wrong type", "missing"])
def test_cli_exits_2_and_writes_nothing(tmp_path: Path, case: str) -> None:
    path = tmp_path / "bad.toml"
    if case != "missing":
        path.write_text(BAD[case][0])
    out = tmp_path / "out"
    proc = run_cli("generate", str(path), "--seeds", "0", "--out", str(out), "--workers", "1")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simharness: error: ") and str(path) in lines[0]
    if case == "missing":
        assert "scenario file not found" in lines[0]
    assert not out.exists() and proc.stdout == ""
    check = run_cli("scenario", str(path))
    assert check.returncode == 2 and check.stderr.strip() == lines[0]


def test_the_simulator_seed_stays_in_range(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(GOOD.replace('backend = "sumo"', 'backend = "sumo"\nseed = 2147483000'))
    spec = load_scenario(path)
    assert spec.sim_seed(647) == 2**31 - 1
    with pytest.raises(UserError, match=r"key 'seed' = 2147483000 plus job seed 648 is 2147483648, outside"):
        spec.sim_seed(648)
