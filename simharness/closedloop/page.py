"""The closed-loop report page: `report.md` from the scores.json files of a run, with its figures."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from simharness.closedloop.aggregation import SCORECARD_ROWS
from simharness.io.parquet import atomic_write_text
from simharness.report import plot_online_error_by_type, plot_scorecard
from simharness.scene import AgentType


def write_report(run_dir: Path | str, title: str = "Closed-loop report", extra_md: str = "",
                 closedloop_dir: Path | str | None = None) -> Path:
    """`report.md` in run_dir from the closed-loop scores.json files in closedloop_dir (default run_dir;
    its scores.json, or */scores.json for several egos): the scorecard table with 95% CIs, ego collisions
    by type, online error by type, figures and animations; `extra_md` goes first (other sections).
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
        lines += ["## Closed loop", "",
                  f"Scenario `{first.get('scenario')}`, background reaction `{first.get('reaction')}`, "
                  f"seeds {first.get('seeds')}; mean [95% bootstrap CI] over episodes.", ""]

        def cell(d: dict) -> str:
            m = d.get("mean", float("nan")) if isinstance(d, dict) else float("nan")
            return "n/a" if not np.isfinite(m) else f"{m:.2f} [{d['lo']:.2f}, {d['hi']:.2f}]"

        names = list(scores)
        lines += ["| | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
        lines.append("| episodes | " + " | ".join(str(scores[n]["episodes"]) for n in names) + " |")
        for key, label in SCORECARD_ROWS:
            lines.append(f"| {label} | " + " | ".join(cell(scores[n].get(key, {})) for n in names) + " |")
        lines += ["", "Ego collisions by the other agent's type (total over episodes):", "",
                  "| type | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
        for t in AgentType:
            lines.append(f"| {t.label} | " + " | ".join(str(scores[n]["collisions_by_type"][t.label]["total"])
                                                       for n in names) + " |")
        fig = plot_scorecard(scores, src / "scorecard.png")
        lines += ["", f"![scorecard]({link(fig)})", ""]
        if any(scores[n].get("online_by_type") for n in names):
            fig2 = plot_online_error_by_type(scores, src / "online_error_by_type.png")
            lines += ["Online prediction error by agent type (each forecast against what the agents did next):", "",
                      f"![online error by type]({link(fig2)})", ""]
        gifs = sorted(src.glob("*.gif")) + sorted(src.glob("*/*.gif"))
        for g in gifs[:4]:
            lines += [f"![episode]({link(g)})", ""]
    path = run_dir / "report.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
