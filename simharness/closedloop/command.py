"""The `closedloop` command and the demo's closed-loop step: run egos over seeds, write scores and reports."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from simharness.closedloop.aggregation import aggregate, scorecard_table
from simharness.closedloop.episode import _predictor, _slug, prepare_spec, run_closed_loop
from simharness.errors import UserError
from simharness.scenario import ScenarioSpec, load_scenario
from simharness.sim.base import RoadGeometry


def write_run(out: Path, spec: ScenarioSpec, predictor: str, results: Sequence[dict[str, Any]], animate: int = 0
              ) -> dict[str, Any]:
    """scores.json, episodes/ (Parquet via write_dataset) and animations of one ego's episodes under `out`."""
    from simharness.io.parquet import atomic_write_bytes, dumps, software_versions, write_dataset

    out.mkdir(parents=True, exist_ok=True)
    scores = aggregate([r["scores"] for r in results])
    scores.update({"predictor": predictor, "scenario": spec.name, "reaction": spec.ego.reaction,
                   "config_hash": spec.config_hash(), "versions": software_versions(),
                   "per_episode": [r["scores"] for r in results]})
    scenes = [r["scene"] for r in results if "scene" in r]
    if scenes:
        write_dataset(scenes, out / "episodes", {"source": "closedloop", "predictor": predictor,
                                                  "scenario": spec.to_dict(), "seeds": scores["seeds"],
                                                  "config_hash": spec.config_hash(), "road": results[0]["road"]},
                      overwrite=True)
    if animate:
        from simharness.report import animate_episode

        for r in [r for r in results if "forecasts" in r][:animate]:
            frames, forecasts = r["forecasts"]
            animate_episode(r["scene"], out / f"episode-seed{r['scores']['seed']:06d}.gif",
                            road=RoadGeometry.from_dict(r["road"]), forecast_frames=frames, forecasts=forecasts)
    atomic_write_bytes(out / "scores.json", (dumps(scores, indent=1) + "\n").encode())
    return scores


def closedloop_command(args: Any) -> int:
    """`simharness closedloop SCENARIO --predictor NAME[,NAME...] --seeds 0-19`: scorecard + scores.json."""
    spec = prepare_spec(load_scenario(args.scenario), args.reaction)
    names = [n.strip() for n in str(args.predictor).split(",") if n.strip()]
    if not names:
        raise UserError("--predictor: expected a name (traphic, const-vel, oracle, none) or a run folder")
    out = Path(args.out)
    all_scores = {}
    for name in names:
        results = run_closed_loop(spec, name, args.seeds, args.workers, args.executor, args.address,
                                  keep_forecasts=args.seeds[: args.animate])
        folder = out if len(names) == 1 else out / _slug(name)
        all_scores[name] = write_run(folder, spec, name, results, animate=args.animate)
    if len(names) > 1:
        from simharness.io.parquet import atomic_write_bytes

        atomic_write_bytes(out / "scorecard.json", (json.dumps(
            {n: {k: v for k, v in s.items() if k != "per_episode"} for n, s in all_scores.items()},
            indent=1, default=float) + "\n").encode())
    from simharness.closedloop.page import write_report

    print(f"{spec.name}: reaction {spec.ego.reaction}, {len(args.seeds)} seeds "
          f"(mean [95% bootstrap CI])")
    print(scorecard_table(all_scores))
    print(f"wrote {out / 'scores.json' if len(names) == 1 else out / 'scorecard.json'}, "
          f"report {write_report(out)}")
    return 0


def demo_closed_loop(out: Path, seeds: Sequence[int] = (0, 1), duration: float = 20.0, workers: int = 2,
                     scenario: str = "sumo_arterial_dense", reaction: str = "cut_in", extra_md: str = "") -> Path:
    """The demo's closed-loop step: TraPHic (when its weights ship), constant velocity, oracle and no
    prediction on a few seeds; prints the scorecard, writes out/closedloop/<ego>/ and out/report.md
    (with one animation). Returns the report's path."""
    from simharness.closedloop.page import write_report

    spec = prepare_spec(load_scenario(scenario), reaction).with_overrides({"duration": float(duration)})
    egos = ["traphic", "const-vel", "oracle", "none"]
    try:
        _predictor("traphic")
    except (UserError, OSError) as e:
        print(f"      (TraPHic left out of the closed loop: {e})", file=sys.stderr)
        egos.remove("traphic")
    scores = {}
    for ego in egos:
        results = run_closed_loop(spec, ego, list(seeds), workers=workers,
                                  keep_forecasts=list(seeds)[:1] if ego == egos[0] else ())
        scores[ego] = write_run(Path(out) / "closedloop" / _slug(ego), spec, ego, results,
                                animate=1 if ego == egos[0] else 0)
    print(f"{spec.name}, reaction {spec.ego.reaction}, seeds {list(seeds)} x {duration:g} s "
          "(mean [95% bootstrap CI])")
    print(scorecard_table(scores))
    return write_report(out, title="simharness demo", extra_md=extra_md, closedloop_dir=Path(out) / "closedloop")
