"""The `closedloop` command and the demo's closed-loop step: run egos over seeds, write scores and reports."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from simharness.closedloop.aggregation import aggregate, scorecard_table, strict_dumps
from simharness.closedloop.episode import _slug, prepare_spec, reaction_of, run_closed_loop
from simharness.errors import UserError
from simharness.io.folders import prepare_output
from simharness.scenario import ScenarioSpec, load_scenario
from simharness.sim.base import RoadGeometry

BASELINE = "const-vel"  # the ego every other is paired against when it is run


def write_run(out: Path, spec: ScenarioSpec, predictor: str, results: Sequence[dict[str, Any]], animate: int = 0
              ) -> dict[str, Any]:
    """scores.json, episodes/ (Parquet via write_dataset) and animations of one ego's episodes under `out`."""
    from simharness.io.parquet import atomic_write_bytes, software_versions, write_dataset

    out.mkdir(parents=True, exist_ok=True)
    scores = aggregate([r["scores"] for r in results])
    scores.update({"predictor": predictor, "scenario": spec.name, "reaction": reaction_of(spec),
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
    atomic_write_bytes(out / "scores.json", (strict_dumps(scores) + "\n").encode())  # NaN written as null
    return scores


def closedloop_command(args: Any) -> int:
    """`simharness closedloop SCENARIO --predictor NAME[,NAME...] --seeds 0-19`: scorecard + scores.json."""
    spec = prepare_spec(load_scenario(args.scenario), args.reaction)
    for seed in args.seeds:  # the seed the simulator gets stays 32-bit, or one line before any work
        spec.sim_seed(seed)
    names = [n.strip() for n in str(args.predictor).split(",") if n.strip()]
    if not names:
        raise UserError("--predictor: expected a name (traphic, const-vel, oracle, none) or a run folder")
    out = Path(args.out)
    prepare_output(out, getattr(args, "force", False))
    all_scores = {}
    for name in names:
        results = run_closed_loop(spec, name, args.seeds, args.workers, args.executor, args.address,
                                  keep_forecasts=args.seeds[: args.animate], planner=getattr(args, "planner", "pdm"))
        folder = out if len(names) == 1 else out / _slug(name)
        all_scores[name] = write_run(folder, spec, name, results, animate=args.animate)
    paired = paired_verdicts(spec.name, {n: s["per_episode"] for n, s in all_scores.items()})
    if len(names) > 1:
        from simharness.io.parquet import atomic_write_bytes

        card = {n: {k: v for k, v in s.items() if k != "per_episode"} for n, s in all_scores.items()}
        if paired:
            card["paired"] = paired
        atomic_write_bytes(out / "scorecard.json", (strict_dumps(card) + "\n").encode())
    from simharness.closedloop.page import write_report

    print(f"{spec.name}: reaction {reaction_of(spec)}, {len(args.seeds)} seeds "
          f"(mean [95% bootstrap CI])")
    print(scorecard_table(all_scores))
    for name, p in paired.items():
        print(f"{name} minus {BASELINE}, paired on seeds: " + "; ".join(
            f"{label} {p[k]['pooled']['mean']:+.3f} [{p[k]['pooled']['lo']:+.3f}, {p[k]['pooled']['hi']:+.3f}]: "
            f"{p[k]['pooled']['verdict']}" if p[k]["pooled"]["n"] else f"{label} n/a"
            for k, label in (("at_fault_collided", "at-fault"), ("composite", "composite"))))
    print(f"wrote {out / 'scores.json' if len(names) == 1 else out / 'scorecard.json'}, "
          f"report {write_report(out)}")
    return 0


def paired_verdicts(scenario: str, per_episode: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """Each ego minus constant velocity, paired on seeds, when constant velocity is among them (else {}):
    {ego: {key: {"pooled": {mean, lo, hi, half_width, n, verdict}, "scenarios": {...}}}} for at-fault,
    collision and composite (`suite.paired_against`)."""
    from simharness.closedloop.suite import COMPARED, paired_against

    if BASELINE not in per_episode or len(per_episode) < 2:
        return {}
    episodes = {scenario: per_episode}
    return {n: {k: paired_against(episodes, n, BASELINE, k) for k in COMPARED} for n in per_episode if n != BASELINE}
