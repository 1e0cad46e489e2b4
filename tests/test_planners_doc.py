"""docs/planners.md: its SB3 example runs as written, with a tiny step count and fewer episodes."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

PAGE = Path(__file__).resolve().parents[1] / "docs" / "planners.md"
SHRINK = {"TIMESTEPS = 200_000": "TIMESTEPS = 256", "n_envs=4": "n_envs=2", "n_eval_episodes=5": "n_eval_episodes=1",
          '{"duration": 30.0}': '{"duration": 4.0}', "range(3)": "range(1)"}


def example() -> str:
    text = PAGE.read_text()
    found = re.search(r"<!-- planners-doc-example -->\s*```python\n(.*?)```", text, re.S)
    assert found, "docs/planners.md lost its example block"
    return found.group(1)


def test_the_example_is_the_one_the_page_shows():
    code = example()
    for old in SHRINK:  # every shrink applies: the page and this test cannot drift apart silently
        assert old in code, old


def test_the_sb3_example_runs(tmp_path):
    code = example()
    for old, new in SHRINK.items():
        code = code.replace(old, new)
    root = str(PAGE.parents[1])
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=900,
                          env={"PYTHONPATH": root, "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "mean return" in proc.stdout and re.search(r"^0 collided \d\.\d progress -?\d", proc.stdout, re.M)
    assert (tmp_path / "ppo_highway_dense.zip").is_file()
