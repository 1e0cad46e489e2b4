"""The report's figures and pages: scorecard ranges, the ego's view window, the episode animation, the
closed-loop page, and `make demo` end to end (slow)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import make_scene
from PIL import Image

from simharness.closedloop.aggregation import SCORECARD_ROWS
from simharness.closedloop.page import COMPOSITE_NOTE, write_report
from simharness.report import animate_episode, ego_window, panel_ylim, plot_rmse_curve, plot_scorecard
from simharness.scene import AgentType
from simharness.sim.base import RoadGeometry

ROAD = RoadGeometry(drivable=(np.array([[-100.0, -5.0], [400.0, -5.0], [400.0, 5.0], [-100.0, 5.0]]),),
                    sidewalks=(np.array([[-100.0, 5.0], [400.0, 5.0], [400.0, 7.0], [-100.0, 7.0]]),
                               np.array([[-100.0, -7.0], [400.0, -7.0], [400.0, -5.0], [-100.0, -5.0]])))


def test_rates_and_composite_span_their_whole_scale_even_when_all_zero():
    zeros = np.zeros(4)
    assert panel_ylim("collision_rate", zeros) == (0.0, 1.0)  # not matplotlib's -0.04..0.04 band
    assert panel_ylim("at_fault_collision_rate", np.array([0.0, 0.5])) == (0.0, 1.0)
    assert panel_ylim("composite", np.array([0.2, 0.9])) == (0.0, 1.0)
    lo, hi = panel_ylim("progress_m", np.array([50.0, 120.0, np.nan]))
    assert lo == 0.0 and hi == pytest.approx(132.0)
    assert panel_ylim("online_ade", np.array([np.nan, np.nan])) == (0.0, 1.0)  # no forecasts at all: still a range


def test_ego_window_spans_the_road_across_and_follows_the_ego():
    x0, y0, x1, y1 = ego_window(np.array([150.0, -2.0]), ROAD, behind=20.0, ahead=45.0)
    assert (x0, x1) == (130.0, 195.0)
    assert y0 <= -7.0 and y1 >= 7.0  # sidewalks included
    assert y1 - y0 <= 7.0 * 2 + 2 * 1.0 + 1e-9  # and no more than a margin beyond: the frame is not half empty
    _, y0, _, y1 = ego_window(np.array([150.0, 20.0]), ROAD)  # an ego off the road stays in view
    assert y0 < 20.0 < y1
    _, y0, _, y1 = ego_window(np.array([0.0, 3.0]), None)
    assert (y0, y1) == (-5.0, 11.0)


def test_animation_follows_the_ego_with_a_frame_per_recorded_frame(tmp_path):
    scene = make_scene(num_agents=6, num_frames=12)
    scene.meta.update({"predictor": "const-vel", "seed": 3})
    gif = animate_episode(scene, tmp_path / "episode.gif", road=ROAD)
    im = Image.open(gif)
    assert im.n_frames == int(scene.valid[scene.ego].sum())
    w, h = im.size
    assert 2.0 < w / h < 6.0  # a strip the shape of the road window plus its legend, not a square half empty


def test_scorecard_and_rmse_curve_are_written(tmp_path):
    scores = {n: {"composite": {"mean": m, "lo": m - 0.1, "hi": m + 0.1},
                  "collision_rate": {"mean": 0.0, "lo": 0.0, "hi": 0.0},
                  "at_fault_collision_rate": {"mean": 0.0, "lo": 0.0, "hi": 0.0},
                  "progress_m": {"mean": 90.0, "lo": 80.0, "hi": 100.0},
                  "online_ade": {"mean": None, "lo": None, "hi": None} if n == "none" else
                  {"mean": 1.2, "lo": 1.0, "hi": 1.4}} for n, m in (("const-vel", 0.5), ("none", 0.7))}
    assert plot_scorecard(scores, tmp_path / "scorecard.png").stat().st_size > 0
    curve = plot_rmse_curve({"traphic": [0.4, 1.3, 2.8], "const-vel": [0.6, 2.1, 4.4]}, tmp_path / "rmse.png")
    assert Image.open(curve).size[0] > 0


def _scores(name: str, at_fault: float) -> dict:
    """A scores.json as `write_run` writes it (the page reads only these keys)."""
    ci = {"mean": at_fault, "lo": 0.0, "hi": at_fault}
    out = {key: {"mean": 0.5, "lo": 0.4, "hi": 0.6} for key, _ in SCORECARD_ROWS}
    out.update({"predictor": name, "scenario": "cut_in", "reaction": "reactive", "seeds": [0, 1], "episodes": 2,
                "collision_rate": ci, "at_fault_collision_rate": ci,
                "collisions_by_type": {t.label: {"total": int(at_fault > 0 and t == AgentType.CAR)}
                                       for t in AgentType}})
    return out


def test_page_explains_the_composite_and_captions_each_animation(tmp_path):
    for name, rate in (("const-vel", 0.0), ("oracle", 0.0)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "scores.json").write_text(json.dumps(_scores(name, rate)))
    Image.new("RGB", (8, 4)).save(tmp_path / "oracle" / "episode-seed000001.gif")
    text = write_report(tmp_path, loop_md="Egos: the oracle and constant velocity.").read_text()
    assert COMPOSITE_NOTE in text and "Egos: the oracle" in text
    assert "No ego collided with anyone" in text  # an all-zero table is one line, not nine rows of 0
    assert "*ego on oracle forecasts, seed 1:*" in text
    assert (tmp_path / "scorecard.png").is_file()
    (tmp_path / "const-vel" / "scores.json").write_text(json.dumps(_scores("const-vel", 0.5)))
    text = write_report(tmp_path).read_text()
    assert "| car | 1 | 0 |" in text and "| bus |" not in text  # only the types someone collided with


@pytest.mark.slow
def test_demo_runs_end_to_end(tmp_path):
    from simharness.demo import main

    assert main(["--out", str(tmp_path), "--seeds", "1", "--duration", "12", "--loop-seeds", "2"]) == 0
    report = (tmp_path / "report.md").read_text()
    for part in ("## Data set", "## Open loop", "## Closed loop", COMPOSITE_NOTE, "openloop/rmse_curve.png"):
        assert part in report
    animated = sorted(p.parent.name for p in (tmp_path / "closedloop").glob("*/*.gif"))
    assert len(animated) == 2 and "oracle" in animated  # an ego that collided (or const-vel) beside the oracle
    rmse = json.loads((tmp_path / "openloop" / "const-vel" / "metrics.json").read_text())["rmse_per_second"]
    assert len(rmse) == 5
