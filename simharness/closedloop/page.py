"""The closed-loop report page: `report.md` from the scores.json files of a run, with its figures."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from simharness.closedloop.aggregation import SCORECARD_ROWS
from simharness.closedloop.scoring import COMPOSITE_WEIGHTS, MIN_PROGRESS_RATIO
from simharness.io.parquet import atomic_write_text
from simharness.report import plot_online_error_by_type, plot_scorecard
from simharness.scene import AgentType

# Beside the scorecard: what the first row means, in two sentences (formula: docs/closedloop.md).
_W = COMPOSITE_WEIGHTS
COMPOSITE_NOTE = (
    "The composite score (0 to 1, higher is better) is nuPlan's closed-loop score adapted: an episode scores 0 "
    "if the ego caused a collision, left the drivable area or made less than "
    f"{MIN_PROGRESS_RATIO:.0%} of the surrounding traffic's progress, and otherwise the weighted mean of its "
    f"progress relative to that traffic (weight {_W['progress']:g}), keeping its time to collision above the "
    f"threshold throughout ({_W['ttc']:g}) and staying within comfort limits on acceleration and jerk "
    f"({_W['comfort']:g}). Each bar is the mean over the episodes, with its 95% bootstrap confidence interval.")


def gif_caption(gif: Path, src: Path) -> str:
    """Alt text of an episode animation: the ego's predictor (its folder, when not src) and the seed."""
    seed = gif.stem.rsplit("seed", 1)[-1].lstrip("0") or "0"
    ego = f"ego on {gif.parent.name} forecasts, " if gif.parent != src else ""
    return f"{ego}seed {seed}"


def write_report(run_dir: Path | str, title: str = "Closed-loop report", extra_md: str = "",
                 closedloop_dir: Path | str | None = None, loop_md: str = "") -> Path:
    """`report.md` in run_dir from the closed-loop scores.json files in closedloop_dir (default run_dir;
    its scores.json, or */scores.json for several egos): the scorecard table with 95% CIs, ego collisions
    by type, online error by type, figures and animations; `extra_md` goes first (other sections), `loop_md`
    right under the closed-loop heading (what the egos are).
    """
    run_dir = Path(run_dir)
    src = Path(closedloop_dir) if closedloop_dir is not None else run_dir
    files = [src / "scores.json"] if (src / "scores.json").is_file() else sorted(src.glob("*/scores.json"))

    def link(p: Path) -> str:
        return Path(os.path.relpath(p, run_dir)).as_posix()

    scores = {}
    for f in files:
        s = json.loads(f.read_text())
        scores[s.get("predictor", f.parent.name)] = s
    order = ("traphic", "const-vel", "oracle", "static", "none")  # predictors first, then the bracketing references
    scores = dict(sorted(scores.items(), key=lambda kv: (order.index(kv[0]) if kv[0] in order else -1, kv[0])))
    lines = [f"# {title}", ""]
    if extra_md:
        lines += [extra_md, ""]
    if scores:
        first = next(iter(scores.values()))
        lines += ["## Closed loop", "", *([loop_md, ""] if loop_md else []),
                  f"Scenario `{first.get('scenario')}`, background reaction `{first.get('reaction')}`, "
                  f"seeds {first.get('seeds')}; mean [95% bootstrap CI] over episodes.", ""]

        def cell(d: dict) -> str:
            m = d.get("mean") if isinstance(d, dict) else None  # null in scores.json where there was no value
            return "n/a" if m is None or not np.isfinite(m) else f"{m:.2f} [{d['lo']:.2f}, {d['hi']:.2f}]"

        names = list(scores)
        lines += ["| | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
        lines.append("| episodes | " + " | ".join(str(scores[n]["episodes"]) for n in names) + " |")
        for key, label in SCORECARD_ROWS:
            lines.append(f"| {label} | " + " | ".join(cell(scores[n].get(key, {})) for n in names) + " |")
        hit = [t.label for t in AgentType if any(scores[n]["collisions_by_type"][t.label]["total"] for n in names)]
        if hit:
            lines += ["", "Ego collisions by the other agent's type (total over episodes):", "",
                      "| type | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
            lines += [f"| {t} | " + " | ".join(str(scores[n]["collisions_by_type"][t]["total"]) for n in names) + " |"
                      for t in hit]
        else:
            lines += ["", "No ego collided with anyone in these episodes."]
        fig = plot_scorecard(scores, src / "scorecard.png")
        lines += ["", COMPOSITE_NOTE, "", f"![scorecard]({link(fig)})", ""]
        # static's error is every agent's whole displacement: it would dwarf the forecasters' bars
        forecasters = {n: scores[n] for n in names if n != "static" and scores[n].get("online_by_type")}
        if forecasters:
            fig2 = plot_online_error_by_type(forecasters, src / "online_error_by_type.png")
            lines += ["Online prediction error by agent type (each forecast against what the agents did next"
                      + ("; `static` left out, its error is each agent's whole displacement" if "static" in names
                         else "") + "):", "", f"![online error by type]({link(fig2)})", ""]
        gifs = sorted(src.glob("*.gif")) + sorted(src.glob("*/*.gif"))
        for g in gifs[:4]:
            lines += [f"*{gif_caption(g, src)}:*", "", f"![{gif_caption(g, src)}]({link(g)})", ""]
    path = run_dir / "report.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
