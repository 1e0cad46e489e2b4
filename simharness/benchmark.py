"""`simharness benchmark`: the TraPHic paper's comparison, rerun on any data set in one command.

Every method (the paper's four baselines and TraPHic's four variants, plus constant velocity as a
reference) is trained on the same train/val split with the same budget (a `Profile`), then scored by the
same open-loop evaluation on the held-out test scenes. The output folder holds the paper's tables for
that data (ADE/FDE both ways per method, the ablation, the RMSE per horizon second, the data set's
Table 1 figures) as results.md and results.json, the RMSE curve of every method in one PNG, the wall
time each method took to train, and one run folder per method (weights, config, log, metrics).

The orchestration lives here, not in predictor/, because it reads harness pieces (stats, evaluation,
report, executors); each method is one job of an executor (a fresh process, one torch thread).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import math
import sys
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from simharness.errors import UserError
from simharness.io.parquet import atomic_write_text

if TYPE_CHECKING:
    from simharness.executors import JobResult

BASELINES: tuple[str, ...] = ("rnn-ed", "social-lstm", "social-gan", "cs-lstm")
VARIANTS: tuple[str, ...] = ("traphic-b", "traphic-he", "traphic-ho", "traphic")
REFERENCE = "const-vel"  # not in the paper: the floor every learned method must beat
METHODS: tuple[str, ...] = (*BASELINES, *VARIANTS)
LABELS = {"rnn-ed": "RNN-ED", "social-lstm": "S-LSTM", "social-gan": "S-GAN", "cs-lstm": "CS-LSTM",
          "traphic-b": "TraPHic-B", "traphic-he": "TraPHic-He", "traphic-ho": "TraPHic-Ho", "traphic": "TraPHic",
          "const-vel": "Const-vel"}
PROTOCOL = "traphic"  # 3 s history, 5 s future at 5 Hz


@dataclasses.dataclass(frozen=True)
class Profile:
    """The training budget every method gets.

    epochs / warmup_epochs (MSE before the NLL) / batch_size / lr: as in predictor.train.
    max_samples / max_val_samples: caps on training / validation windows (drawn with the seed), None for all.
    stride: recorded frames between training windows ("now"s); 1 uses every frame.
    residual: means as a correction to constant velocity (predictor.models.config); lr_schedule / patience /
    mean_loss / select: the learning-rate schedule, early stopping, the means' loss after the warm-up and the
    validation criterion that picks the checkpoint (predictor.train).
    """

    name: str
    epochs: int
    warmup_epochs: int
    batch_size: int
    lr: float
    max_samples: int | None
    stride: int
    max_val_samples: int | None = None
    seed: int = 0
    residual: bool = True
    lr_schedule: str = "cosine"
    patience: int | None = None
    mean_loss: str = "mse"
    select: str = "ade"  # the scored means; "loss" kept Social-GAN's worst early epochs (docs/results.md)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


PROFILES: dict[str, Profile] = {
    # Minutes on 2 cores for tests: tiny epochs and sample caps; the numbers mean little.
    "quick": Profile("quick", epochs=2, warmup_epochs=1, batch_size=32, lr=1e-3, max_samples=96, stride=10,
                     max_val_samples=64),
    # Between the two: about 10-15 CPU-minutes for all methods on a 10-scene data set.
    "medium": Profile("medium", epochs=5, warmup_epochs=2, batch_size=128, lr=1e-3, max_samples=4096, stride=2,
                      max_val_samples=1024),
    # The paper's 16 epochs, batch 128, Adam at 1e-3, on at most 80,000 windows with early stopping: within 3 hours
    # for all methods on 2 CPU cores (about 1 hour projected at the measured samples/s; docs/results.md).
    "full": Profile("full", epochs=16, warmup_epochs=2, batch_size=128, lr=1e-3, max_samples=80_000, stride=1,
                    max_val_samples=4000, patience=3),
}


@dataclasses.dataclass(frozen=True)
class MethodJob:
    """One method to train (unless the reference) and score; `out` is its run folder."""

    method: str
    data: str
    out: str
    profile: Profile
    protocol: str = PROTOCOL  # evaluation protocol; training windows of its length and rate


def run_method(job: MethodJob) -> dict[str, Any]:
    """Train `job.method` on the train split, score it on the test split -> its row (runs in a worker process)."""
    import torch

    from predictor.predict import ModelPredictor
    from predictor.train import protocol_window, train
    from simharness.evaluation import evaluate
    from simharness.predictors import load_predictor

    torch.set_num_threads(1)  # one process per method: workers share the cores
    p, out = job.profile, Path(job.out)
    row: dict[str, Any] = {"method": job.method, "label": LABELS.get(job.method, job.method)}
    t0 = time.perf_counter()
    if job.method == REFERENCE:
        predictor = load_predictor(REFERENCE)
        row.update(train_s=0.0, params=0, best_epoch=None, train_samples=0, samples_per_s=None)
    else:
        res = train(Path(job.data), model=job.method, out=out, epochs=p.epochs, warmup_epochs=p.warmup_epochs,
                    batch_size=p.batch_size, lr=p.lr, seed=p.seed, max_samples=p.max_samples,
                    window=protocol_window(job.protocol, stride=p.stride), threads=1, progress=False,
                    max_val_samples=p.max_val_samples, model_config={"residual": p.residual},
                    lr_schedule=p.lr_schedule, patience=p.patience, device="auto", mean_loss=p.mean_loss,
                    select=p.select)
        predictor = ModelPredictor.from_run(out)
        row.update(train_s=round(time.perf_counter() - t0, 2),
                   params=int(sum(t.numel() for t in predictor.model.parameters())),
                   best_epoch=res["best_epoch"], train_samples=res["train_samples"],
                   samples_per_s=round(res["samples_per_s"], 1), config_hash=res["config"]["config_hash"])
    t1 = time.perf_counter()
    metrics = evaluate(Path(job.data), predictor, job.protocol, split="test", progress=False, name=job.method)
    row["eval_s"] = round(time.perf_counter() - t1, 2)
    row["metrics"] = metrics
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=1) + "\n")
    return row


def _run_inline(jobs: list[MethodJob]) -> Iterator[JobResult]:
    """`run_method` over jobs in this process, each failure reported as its executor would report it."""
    from simharness.executors import JobResult

    for job in jobs:
        try:
            yield JobResult(job, value=run_method(job))
        except Exception as e:  # a method that fails is reported; the others still run
            yield JobResult(job, error=f"{type(e).__name__}: {e}".splitlines()[0], traceback=traceback.format_exc())


# ---------------------------------------------------------------------------- the run
def benchmark(data: Path, profile: str | Profile = "quick", out: Path = Path("runs/benchmark"), workers: int = 2,
              executor: str = "local", address: str | None = None, methods: tuple[str, ...] | None = None,
              progress: bool = True, protocol: str = PROTOCOL) -> dict[str, Any]:
    """Train and score every method on `data` with one budget; write results.{md,json} and figures to `out`.

    protocol: the evaluation protocol (`simharness.protocols`); methods train on windows of its length and rate.

    methods: a subset of METHODS (default all); the constant-velocity reference is always scored.
    workers: 1 runs every method here in turn; more run one fresh process per method, that many at once.
    Returns the results dict (also results.json). Methods that fail are listed under "failed".
    """
    from tqdm import tqdm

    from predictor.train import load_windows, protocol_window
    from simharness.executors import make_executor
    from simharness.io.parquet import Dataset, software_versions
    from simharness.protocols import get_protocol
    from simharness.stats import dataset_stats

    prof = PROFILES[profile] if isinstance(profile, str) and profile in PROFILES else profile
    if not isinstance(prof, Profile):
        raise UserError(f"unknown benchmark profile {profile!r}; expected one of {', '.join(PROFILES)}")
    chosen = tuple(methods or METHODS)
    unknown = [m for m in chosen if m not in METHODS]
    if unknown:
        raise UserError(f"unknown methods {unknown}; expected some of {', '.join(METHODS)}")
    data, out = Path(data), Path(out)
    get_protocol(protocol)  # an unknown name fails here, before any training
    ds = Dataset(data)  # a bad folder fails here, before any training
    started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    # Build the windows cache once, here, so parallel jobs read it instead of each building it.
    load_windows(data, protocol_window(protocol, stride=prof.stride), progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [MethodJob(m, str(data), str(out / "runs" / m), prof, protocol) for m in (*chosen, REFERENCE)]
    rows: dict[str, dict[str, Any]] = {}
    failed: dict[str, str] = {}
    # One worker: run in this process (imports once, no spawn); more: one fresh process per method.
    results_iter = (_run_inline(jobs) if workers == 1 and executor == "local" and not address
                    else make_executor(executor, workers, address, max_retries=0).map_unordered(run_method, jobs))
    bar = tqdm(total=len(jobs), desc=f"benchmark {prof.name}", unit="method", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    try:
        for r in results_iter:
            name = r.job.method
            if r.ok:
                rows[name] = r.value
                bar.set_postfix_str(f"{name} trained in {r.value['train_s']:.0f} s")
            else:
                failed[name] = r.error or "failed"
                tqdm.write(f"{name} failed: {r.error}\n{r.traceback}", file=sys.stderr)
            bar.update(1)
    finally:
        bar.close()
    order = [m for m in (*chosen, REFERENCE) if m in rows]
    results = {
        "data": str(data), "data_hash": ds.manifest.get("content_hash"), "scenario": ds.info.get("scenario"),
        "profile": prof.to_dict(), "protocol": protocol, "started_utc": started,
        "config_hash": hashlib.sha256(json.dumps([prof.to_dict(), chosen, protocol], sort_keys=True).encode())
        .hexdigest()[:16],
        "methods": {m: rows[m] for m in order}, "failed": failed,
        "stats": dataset_stats(data),
        "verdict": verdict({m: rows[m] for m in order}),
        "versions": software_versions(), "command": sys.argv,
    }
    results["wall_s"] = round(time.perf_counter() - t0, 1)
    write_results(results, out)
    return results


# ---------------------------------------------------------------------------- tables
def _f(v: float | None, digits: int = 2) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{digits}f}"


def verdict(rows: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """TraPHic against the best learned baseline on ADE-RMSE and FDE-RMSE (the paper's claim), as numbers."""
    base = {m: rows[m]["metrics"] for m in BASELINES if m in rows}
    if "traphic" not in rows or not base:
        return {}
    t = rows["traphic"]["metrics"]
    out: dict[str, Any] = {}
    for key in ("ade_rmse", "fde_rmse"):
        best = min(base, key=lambda m: base[m][key])
        out[key] = {"traphic": t[key], "best_baseline": best, "best_baseline_value": base[best][key],
                    "relative_change": round(t[key] / base[best][key] - 1.0, 4)}
    out["beats_every_baseline"] = all(t[k] < min(b[k] for b in base.values()) for k in ("ade_rmse", "fde_rmse"))
    if "cs-lstm" in base:
        out["vs_cs_lstm_ade_rmse"] = round(t["ade_rmse"] / base["cs-lstm"]["ade_rmse"] - 1.0, 4)
    return out


def stats_table(s: dict[str, Any]) -> str:
    """The data set as a row of the paper's Table 1 (agents per frame by type, density, distinct types)."""
    cols = [("pedestrian", "Ped"), ("bicycle", "Bicycle"), ("car", "Car"), ("motorcycle", "Bike"),
            ("scooter", "Scooter"), ("bus", "Bus"), ("truck", "Truck"), ("rickshaw", "Rick")]
    per = s["agents_per_frame_by_type"]
    head = ["Dataset", "#Frames (x10^3)", *[h for _, h in cols], "Total", "Density (/km)", "#Diff",
            "Within 50 m"]
    row = [str(s.get("scenario") or Path(s["dataset"]).name), f"{s['frames'] / 1000:.2f}",
           *[f"{per[k]:.2f}" for k, _ in cols], f"{s['agents_per_frame']:.2f}", _f(s.get("density_per_km"), 1),
           str(s["distinct_types"]), f"{s['agents_within_50m']:.1f}"]
    return _md([head, row])


def _md(rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(rows[0]) + " |", "|" + "|".join("---" for _ in rows[0]) + "|"]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows[1:]])


def _protocol_text(name: str) -> str:
    """"3 s history, 5 s future, 5 Hz" for a protocol name."""
    from simharness.protocols import get_protocol

    p = get_protocol(name)
    return f"{p.history / p.hz:g} s history, {p.future / p.hz:g} s future, {p.hz:g} Hz"


def format_markdown(results: dict[str, Any]) -> str:
    """results.md: data set figures, the main table, S-GAN best-of-K, the ablation, RMSE per second, verdict."""
    rows = results["methods"]
    prof = results["profile"]
    units = next(iter(rows.values()))["metrics"]["units"] if rows else "m"
    lines = [f"# Benchmark: {results.get('scenario') or results['data']}", "",
             f"Profile `{prof['name']}`: {prof['epochs']} epochs ({prof['warmup_epochs']} MSE warm-up), batch "
             f"{prof['batch_size']}, lr {prof['lr']:g}, at most {prof['max_samples'] or 'all'} training windows "
             f"(stride {prof['stride']} frames; validation on at most {prof.get('max_val_samples') or 'all'}), "
             f"seed {prof['seed']}, {'residual over constant velocity' if prof.get('residual') else 'direct'} "
             f"means, checkpoint by validation {prof.get('select', 'loss')}. Protocol `{results['protocol']}` "
             f"({_protocol_text(results['protocol'])}) on the held-out "
             f"test scenes. Data hash `{str(results['data_hash'])[:16]}`, config "
             f"hash `{results['config_hash']}`, wall time {results['wall_s']:.0f} s.", "",
             "## Data set (the paper's Table 1)", "", stats_table(results["stats"]), "",
             f"## Methods ({units}; lower is better)", "",
             "ADE/FDE as RMSE (the paper's tables) and as mean Euclidean error (the field's usual meaning).", ""]
    table = [["Method", "ADE/FDE (RMSE)", "ADE/FDE (mean Euclidean)", "NLL (nats)", "Test samples",
              "Train time (s)", "Train samples/s", "Parameters"]]
    for r in rows.values():
        k = r["metrics"]
        table.append([r["label"], f"{_f(k['ade_rmse'])}/{_f(k['fde_rmse'])}", f"{_f(k['ade'])}/{_f(k['fde'])}",
                      _f(k.get("nll")), str(k["samples"]), _f(r["train_s"], 1), _f(r["samples_per_s"], 0),
                      f"{r['params']:,}"])
    lines += [_md(table), ""]
    if "social-gan" in rows and rows["social-gan"]["metrics"].get("min_ade") is not None:
        k = rows["social-gan"]["metrics"]
        lines += ["S-GAN above is one sample. Best of 20 samples (min over samples per target, mean Euclidean): "
                  f"minADE {_f(k['min_ade'])}, minFDE {_f(k['min_fde'])} {units}.", ""]
    abl = [m for m in VARIANTS if m in rows]
    if abl:
        ref = rows.get("traphic-b", {}).get("metrics")
        table = [["Variant", "Heterogeneous", "Horizon", "ADE/FDE (RMSE)", "ADE-RMSE vs TraPHic-B"]]
        flags = {"traphic-b": ("no", "no"), "traphic-he": ("yes", "no"), "traphic-ho": ("no", "yes"),
                 "traphic": ("yes", "yes")}
        for m in abl:
            k = rows[m]["metrics"]
            rel = f"{100 * (k['ade_rmse'] / ref['ade_rmse'] - 1):+.0f}%" if ref else "-"
            table.append([LABELS[m], *flags[m], f"{_f(k['ade_rmse'])}/{_f(k['fde_rmse'])}", rel])
        lines += ["## Ablation (TraPHic's variants)", "", _md(table), ""]
    secs = max((len(r["metrics"]["rmse_per_second"]) for r in rows.values()), default=0)
    table = [["Method", *[f"{s + 1} s" for s in range(secs)]]]
    for r in rows.values():
        table.append([r["label"], *[_f(v) for v in r["metrics"]["rmse_per_second"]]])
    lines += ["## RMSE per horizon second", "", _md(table), "", "![RMSE per horizon second](rmse_curve.png)",
              "", "![ADE/FDE and training time per method](methods.png)", ""]
    v = results.get("verdict") or {}
    if v:
        a, f = v["ade_rmse"], v["fde_rmse"]
        lines += ["## TraPHic against the best learned baseline", "",
                  f"ADE-RMSE {_f(a['traphic'])} vs {_f(a['best_baseline_value'])} ({LABELS[a['best_baseline']]}): "
                  f"{100 * a['relative_change']:+.1f}%; FDE-RMSE {_f(f['traphic'])} vs "
                  f"{_f(f['best_baseline_value'])} ({LABELS[f['best_baseline']]}): {100 * f['relative_change']:+.1f}%. "
                  f"TraPHic beats every baseline on both: {'yes' if v['beats_every_baseline'] else 'no'}.", ""]
    if results.get("failed"):
        lines += ["## Failed", "", *[f"- {m}: {e}" for m, e in results["failed"].items()], ""]
    return "\n".join(lines)


def write_results(results: dict[str, Any], out: Path) -> None:
    """results.json, results.md, rmse_curve.png and methods.png into `out` (each written whole, then renamed)."""
    from simharness.report import plot_method_bars, plot_rmse_curve

    rows = results["methods"]
    units = next(iter(rows.values()))["metrics"]["units"] if rows else "m"
    if rows:
        plot_rmse_curve({r["label"]: r["metrics"]["rmse_per_second"] for r in rows.values()},
                        out / "rmse_curve.png", units=units,
                        title=f"RMSE per horizon second: {results.get('scenario') or Path(results['data']).name}")
        plot_method_bars({r["label"]: (r["metrics"]["ade_rmse"], r["metrics"]["fde_rmse"], r["train_s"])
                          for r in rows.values()}, out / "methods.png", units=units)
    atomic_write_text(out / "results.json", json.dumps(results, indent=1, default=str) + "\n")
    atomic_write_text(out / "results.md", format_markdown(results) + "\n")


def benchmark_command(args: argparse.Namespace) -> int:
    """CLI: `simharness benchmark --data DIR [--profile quick|medium|full] [--out DIR] [--workers N]`."""
    from simharness.io.folders import prepare_output

    prepare_output(Path(args.out), getattr(args, "force", False))
    profile = PROFILES[args.profile]
    if getattr(args, "residual", True) != profile.residual:
        profile = dataclasses.replace(profile, residual=args.residual)
    res = benchmark(args.data, profile, args.out, workers=args.workers, executor=args.executor,
                    address=args.address, protocol=getattr(args, "protocol", PROTOCOL))
    text = format_markdown(res)
    start = text.index("## Methods")
    print(text[start:text.index("## RMSE per horizon second")].rstrip())
    print(f"-> {Path(args.out) / 'results.md'}, results.json, rmse_curve.png, methods.png")
    if res["failed"]:
        print(f"simharness: {len(res['failed'])} methods failed: {', '.join(res['failed'])}", file=sys.stderr)
        return 1
    return 0
