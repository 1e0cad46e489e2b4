"""Open-loop evaluation of any `Predictor` on a data set: the same code scores TraPHic, constant velocity
and a user's own predictor.

`evaluate(data, predictor, protocol, split)` walks the protocol's windows of the chosen scenes, asks the
predictor for all targets of a window in one call, and returns the metrics dict (metrics.json).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from simharness.errors import UserError
from simharness.io.parquet import atomic_write_text
from simharness.metrics import displacement as dm
from simharness.protocols import EvalProtocol, get_protocol, history_and_truth, prepare, windows
from simharness.scene import AgentType, Predictor, Scene

DENSITY_RADIUS_M = 25.0  # local density: other agents within this radius of the target at "now"


def _local_counts(scene: Scene, now: int, rows: np.ndarray, radius: float) -> np.ndarray:
    """(M,) number of other agents present at `now` within `radius` (scene units) of each target."""
    p = scene.xy[scene.valid[:, now], now]
    d = np.linalg.norm(scene.xy[rows, now][:, None] - p[None], axis=-1)
    return (d <= radius).sum(1) - 1


def evaluate(data: Path, predictor: Predictor, protocol: EvalProtocol | str = "traphic", split: str = "test",
             figure_dir: Path | None = None, progress: bool = True, name: str = "",
             test_scenes: list[str] | None = None) -> dict[str, Any]:
    """Score `predictor` on the `split` scenes ("test": the held-out scenes of training; "all") -> metrics dict.

    test_scenes: the scenes held out by name (leave-one-scene-out, as in `simharness train --test-scenes`);
    with split "test" they are the scenes scored. Without them, a predictor trained on this very data set (its
    `info` records the data set's content hash and the split, as `simharness train` runs and shipped weights do)
    is scored on the test scenes its training recorded; any other on the hash split training would hold out.

    Keys: ade, fde (mean Euclidean), ade_rmse, fde_rmse, rmse_per_second (list), nll (or None when the
    predictor gives no uncertainty), miss_rate_2m, min_ade/min_fde (sampled forecasts only), samples,
    by_type {type: {ade, fde, ade_rmse, fde_rmse, samples}}, by_density {bin: ...}, units, protocol, split.
    """
    from tqdm import tqdm

    from simharness.io.parquet import Dataset
    from simharness.predictors import split_scenes

    protocol = get_protocol(protocol) if isinstance(protocol, str) else protocol
    ds = Dataset(Path(data))
    recorded = None if test_scenes else recorded_test_scenes(predictor, ds.content_hash, list(ds.scene_ids))
    if split == "test" and recorded is not None:
        chosen = recorded
    elif split == "test":
        chosen = split_scenes(list(ds.scene_ids), test_scenes=test_scenes)["test"]
    elif split == "all":
        if test_scenes:
            raise UserError("--test-scenes names the held-out scenes of --split test, not of --split all")
        chosen = list(ds.scene_ids)
    else:
        raise UserError(f"unknown split {split!r}; expected test or all")
    if progress:
        print(split_line(split, chosen, list(ds.scene_ids), test_scenes, recorded=recorded is not None))
    preds, truths, valids, sigmas, modes, types, counts = [], [], [], [], [], [], []
    units, step_dt, example, scale, has_scale = None, None, None, 1.0, False
    for sid in tqdm(chosen, desc=f"evaluate {name}".strip(), unit="scene", disable=not progress):
        scene = prepare(ds.scene(sid), protocol)  # eth-ucy: skip frames nobody was annotated in
        if units is not None and scene.units != units:
            raise UserError(f"{data}: scene {sid!r} is in {scene.units!r}, others in {units!r}")
        units, step_dt = scene.units, scene.dt * protocol.step(scene.dt)
        has_scale = "units_per_m" in scene.meta
        scale = float(scene.meta.get("units_per_m", 1.0)) if scene.units != "m" else 1.0
        wins = list(windows(scene, protocol))
        for now, rows in wins:
            hist, truth, tvalid = history_and_truth(scene, now, protocol)
            fc = predictor.predict(hist, rows, protocol.future)
            if fc.mean.shape != (len(rows), protocol.future, 2):
                raise UserError(f"predictor {name!r} returned mean {fc.mean.shape}, expected "
                                f"({len(rows)}, {protocol.future}, 2)")
            preds.append(fc.mean)
            truths.append(truth[rows])
            valids.append(tvalid[rows])
            sigmas.append(fc.sigma_rho)
            modes.append(fc.modes)
            types.append(scene.agent_type[rows])
            counts.append(_local_counts(scene, now, rows, DENSITY_RADIUS_M * scale))
        if example is None and wins:  # the figure: the busiest window of the first scene
            now, rows = max(wins, key=lambda w: len(w[1]))
            hist, truth, _ = history_and_truth(scene, now, protocol)
            fc = predictor.predict(hist, rows, protocol.future)
            example = (scene, now, rows, hist.xy[rows], truth[rows], fc, ds.road)
    if not preds:
        raise UserError(f"{data}: no complete {protocol.name} windows ({protocol.history} + {protocol.future} "
                        f"frames) in the {split} scenes")
    pred, truth, valid = np.concatenate(preds), np.concatenate(truths), np.concatenate(valids)
    agent_type, count = np.concatenate(types), np.concatenate(counts)
    out: dict[str, Any] = {"predictor": name, "protocol": dataclasses_dict(protocol), "split": split,
                           "scenes": len(chosen), "scene_ids": list(chosen), "units": units,
                           **dm.summary(pred, truth, valid)}
    out["rmse_per_second"] = [float(v) for v in dm.rmse_per_second(pred, truth, valid, step_dt)]
    # 2 m in the scene's units; pixel data without a scale gets no miss rate rather than a wrong one.
    out["miss_rate_2m"] = dm.miss_rate(pred, truth, valid, 2.0 * scale) if units == "m" or has_scale else None
    out["nll"] = (dm.bivariate_nll(pred, np.concatenate(sigmas), truth, valid)
                  if all(s is not None for s in sigmas) else None)
    if all(m is not None for m in modes):
        out["min_ade"], out["min_fde"] = dm.min_ade_fde(np.concatenate(modes), truth, valid)
    out["by_type"] = dm.by_group(pred, truth, valid, agent_type, {int(t): t.label for t in AgentType})
    bins, names = dm.density_bins(count)
    out["by_density"] = dm.by_group(pred, truth, valid, bins, names)
    out["density_radius"] = DENSITY_RADIUS_M
    if figure_dir is not None:
        from simharness.report import plot_forecasts, plot_rmse_curve

        figure_dir.mkdir(parents=True, exist_ok=True)
        plot_rmse_curve({name or "predictor": out["rmse_per_second"]}, figure_dir / "rmse_curve.png", units=units)
        scene, now, rows, hxy, txy, fc, road = example
        # The target that moves most of each agent type, so that the figure shows the mix.
        moved = np.argsort(np.linalg.norm(txy[:, -1] - hxy[:, -1], axis=-1))[::-1]
        _, first = np.unique(scene.agent_type[rows[moved]], return_index=True)
        pick = moved[np.sort(first)][:4]
        plot_forecasts(scene, now, rows[pick], hxy[pick], txy[pick], fc.mean[pick], figure_dir / "forecasts.png",
                       sigma_rho=None if fc.sigma_rho is None else fc.sigma_rho[pick], road=road,
                       title=f"{name}: history (black), truth (green), prediction (red, 1 sigma)")
        out["figures"] = ["rmse_curve.png", "forecasts.png"]
    return _finite(out)


def recorded_test_scenes(predictor: Predictor, data_hash: str, scene_ids: list[str]) -> list[str] | None:
    """The test scenes a trained predictor's config records (`info["split"]["test"]`), when it was trained on
    the data set of content hash `data_hash` and those scenes are in it; None otherwise (another data set, a
    predictor without a recorded split)."""
    info = getattr(predictor, "info", None)
    if not isinstance(info, dict) or info.get("data_hash") != data_hash:
        return None
    test = (info.get("split") or {}).get("test") if isinstance(info.get("split"), dict) else None
    if not isinstance(test, list) or not test or not all(isinstance(s, str) and s in scene_ids for s in test):
        return None
    return sorted(set(test))


def split_line(split: str, chosen: list[str], scene_ids: list[str], test_scenes: list[str] | None,
               recorded: bool = False) -> str:
    """The line `evaluate` prints first: which scenes it scores, of how many, and why those (recorded: the
    test scenes the model's training recorded in its config.json)."""
    head = f"scoring split {split!r}: {len(chosen)} of {len(set(scene_ids))} scenes"
    if split == "all":
        return head
    if test_scenes:
        why = "named by --test-scenes"
    elif recorded:
        why = "the ones the model's training held out, as its run config records"
    elif any(s.endswith("_val") for s in scene_ids):
        why = "the data set's own test scenes, ids without _train / _val"
    else:
        why = "the ones `simharness train` holds out by a hash of the scene ids"
    names = ", ".join(chosen[:10]) + (f" and {len(chosen) - 10} more" if len(chosen) > 10 else "")
    return f"{head} ({why}; --split all for every scene): {names}"


def dataclasses_dict(protocol: EvalProtocol) -> dict[str, Any]:
    import dataclasses

    return dataclasses.asdict(protocol)


def _finite(obj: Any) -> Any:
    """NaN -> None so metrics.json is strict JSON."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def format_table(results: dict[str, dict[str, Any]]) -> str:
    """Methods side by side: ADE/FDE both ways, NLL, samples."""
    f = lambda v: "n/a" if v is None else f"{v:.3f}"  # noqa: E731
    units = next(iter(results.values())).get("units", "m")
    lines = [f"{'method':<14} {'ADE':>8} {'FDE':>8} {'ADE-RMSE':>9} {'FDE-RMSE':>9} {'NLL':>8} {'samples':>8}",
             f"{'':<14} {'(' + units + ', mean Euclidean)':>17} {'(' + units + ', RMSE, paper)':>19}"]
    for name, r in results.items():
        lines.append(f"{name:<14} {f(r['ade']):>8} {f(r['fde']):>8} {f(r['ade_rmse']):>9} {f(r['fde_rmse']):>9} "
                     f"{f(r.get('nll')):>8} {r['samples']:>8}")
    return "\n".join(lines)


def evaluate_command(args: argparse.Namespace) -> int:
    """`simharness evaluate --data DIR --model RUN|traphic|const-vel [--out DIR] [--protocol] [--split]`."""
    from simharness.io.folders import prepare_output
    from simharness.plugins import label, load_predictor

    predictor = load_predictor(args.model)
    name = label(args.model)  # "dir/mine.py:Model" -> "mine:Model"; a run folder -> its name
    out_dir = Path(args.out) if args.out is not None else Path("runs/evaluate") / name
    prepare_output(out_dir, getattr(args, "force", False))
    res = evaluate(args.data, predictor, get_protocol(args.protocol), split=args.split, figure_dir=out_dir, name=name,
                   test_scenes=getattr(args, "test_scenes", None))
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "metrics.json", json.dumps(res, indent=1) + "\n")
    print(format_table({name: res}))
    secs = ", ".join(f"{v:.2f}" if v is not None else "n/a" for v in res["rmse_per_second"])
    print(f"RMSE per second ({res['units']}): {secs}")
    print("by type: " + ", ".join(f"{t} {r['ade']:.2f}/{r['fde']:.2f} ({r['samples']})"
                                  for t, r in res["by_type"].items()))
    print(f"-> {out_dir / 'metrics.json'}, {out_dir / 'rmse_curve.png'}, {out_dir / 'forecasts.png'}")
    return 0
