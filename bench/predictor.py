"""Predictor benchmark: training throughput, batched inference time, and the accuracy table.

    python bench/predictor.py            # --quick (default): small budget, a few minutes on 2 cores
    python bench/predictor.py --full     # more data and the paper's 16 epochs
    python bench/predictor.py --data DIR # reuse a data set generated from sumo_arterial_dense
    python bench/predictor.py --data DIR --speed --threads 1,2   # only throughput and inference time
    python bench/predictor.py --data DIR --methods               # training samples/s of every method

Prints figures measured in this run: samples/s of training (batch building from the cached index +
forward + backward + Adam step) and ms per batched forecast of every agent of a ~100-agent frame (the
shipped TraPHic), each at 1 and 2 threads, wall-clock and CPU time, with the load average (the machine is
shared: CPU time is what an idle machine would give one thread), and
ADE/FDE (mean Euclidean and RMSE) of TraPHic, its three ablations and constant velocity on the held-out
scenes, all trained with the same budget; writes the RMSE-per-second figure of all methods.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

# This file is named like the `predictor` package: drop bench/ from the path so the package is imported.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
os.environ.setdefault("OMP_NUM_THREADS", "1")  # one thread: two spin-wait badly on a shared, loaded machine

import numpy as np  # noqa: E402
import torch  # noqa: E402

from predictor.features import WindowConfig  # noqa: E402
from predictor.losses import mse  # noqa: E402
from predictor.models import build_model  # noqa: E402
from predictor.models.const_vel import ConstantVelocity  # noqa: E402
from predictor.predict import ModelPredictor  # noqa: E402
from predictor.train import load_windows, train  # noqa: E402
from simharness.evaluation import evaluate, format_table  # noqa: E402
from simharness.io.parquet import Dataset  # noqa: E402
from simharness.report import plot_rmse_curve  # noqa: E402

VARIANTS = ("traphic-b", "traphic-he", "traphic-ho", "traphic")
METHODS = ("rnn-ed", "social-lstm", "social-gan", "cs-lstm", *VARIANTS)


def _load() -> str:
    """The machine's load average over 1 minute, for the record beside every timing."""
    return f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"


def throughput(data: Path, threads: int, batches: int = 40, batch_size: int = 128, model: str = "traphic",
               residual: bool = False) -> tuple[float, float]:
    """Training samples per second of `model`, batch building from the cached index + forward + backward + Adam
    step (Social-GAN: its discriminator and generator steps), after 5 warm-up batches -> (wall-clock, CPU-time)
    samples/s. CPU time excludes waiting for the cores, so it is the rate of an otherwise idle machine (for one
    thread; with more it adds the threads' times up)."""
    torch.set_num_threads(threads)
    store = load_windows(data, WindowConfig(), progress=False)
    torch.manual_seed(0)
    net = build_model(model, {"history": store.H, "future": store.F, **({"residual": True} if residual else {})})
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, fused=True)
    rng = np.random.default_rng(0)
    t0 = c0 = 0.0
    for i in range(batches + 5):
        if i == 5:
            t0, c0 = time.perf_counter(), time.process_time()
        b = store.batch(rng.integers(0, len(store), batch_size)).tensors()
        if hasattr(net, "training_step"):
            net.training_step(b, "mse", opt)
            continue
        loss = mse(net(b), b["fut"], b["fut_valid"])
        opt.zero_grad()
        loss.backward()
        opt.step()
    n = batches * batch_size
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def inference_ms(data: Path, predictor: ModelPredictor, threads: int, calls: int = 30) -> tuple[float, float, int]:
    """One predict() call for every agent present at a frame with ~100 agents -> (median wall ms, median CPU ms,
    agents)."""
    predictor.threads = threads  # predict() runs with its own thread count
    scene = Dataset(data).scene(0)
    counts = scene.valid.sum(0)
    now = int(np.argmin(np.abs(counts - 100) + 1000 * (np.arange(scene.num_frames) < 15)))
    hist = scene.slice_frames(now - 14, now + 1)
    rows = np.flatnonzero(hist.valid[:, -1])
    for _ in range(3):
        predictor.predict(hist, rows, 25)
    wall, cpu = [], []
    for _ in range(calls):
        t, c = time.perf_counter(), time.process_time()
        predictor.predict(hist, rows, 25)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return 1000 * float(np.median(wall)), 1000 * float(np.median(cpu)), len(rows)


def speed(data: Path, predictor: ModelPredictor, threads: list[int]) -> dict[str, dict[str, float]]:
    """Throughput and inference at each thread count, printed with the load they were measured under."""
    out: dict[str, dict[str, float]] = {}
    for k in threads:
        wall, cpu = throughput(data, k)
        print(f"training throughput, {k} thread(s): {wall:.0f} samples/s wall-clock, {cpu:.0f} samples/s of CPU "
              f"time (batch 128, data loading included; {_load()}; target >= 1000, the authors' code ~200)")
        ms, cms, n = inference_ms(data, predictor, k)
        print(f"inference, {k} thread(s): {ms:.1f} ms wall-clock, {cms:.1f} ms CPU, median of 30 calls predicting all "
              f"{n} agents of a frame in one call ({_load()}; target <= 20 ms)")
        out[str(k)] = {"samples_per_s": wall, "samples_per_cpu_s": cpu, "inference_ms": ms, "inference_cpu_ms": cms,
                       "agents": n, "load": os.getloadavg()[0]}
    torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=Path("runs/bench_predictor"))
    ap.add_argument("--max-samples", type=int, default=None, help="override the training windows per model")
    ap.add_argument("--epochs", type=int, default=None, help="override the epochs per model")
    ap.add_argument("--speed", action="store_true", help="only the throughput and inference figures")
    ap.add_argument("--threads", default="1", help="thread counts to time, comma-separated (1,2 compares)")
    ap.add_argument("--methods", action="store_true",
                    help="only the training samples/s of every method (the paper's baselines and TraPHic's variants)")
    args = ap.parse_args()
    torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))
    seeds, duration, samples, epochs, warmup = ("0-5", 40, 3000, 3, 1) if not args.full else ("0-19", 60, None, 16, 2)
    samples, epochs = args.max_samples or samples, args.epochs or epochs
    data = args.data or args.out / "data"
    if args.data is None and not (data / "_manifest.json").is_file():
        subprocess.run([sys.executable, "-m", "simharness", "generate", "sumo_arterial_dense", "--seeds", seeds,
                        "--out", str(data), "--duration", str(duration)], check=True)
    t = time.perf_counter()
    load_windows(data, WindowConfig())
    print(f"windows index built or loaded in {time.perf_counter() - t:.1f} s")
    if args.methods:
        for name in METHODS:
            wall, cpu = throughput(data, 1, batches=20, model=name)
            print(f"{name}: {wall:.0f} training samples/s wall-clock, {cpu:.0f} of CPU time (1 thread, batch 128, "
                  f"data loading included; {_load()}; target >= 1000)", flush=True)
        return 0
    timing = speed(data, ModelPredictor.shipped("traphic"), [int(k) for k in args.threads.split(",")])
    if args.speed:
        return 0
    results, curves, train_s = {}, {}, {}
    for name in VARIANTS:
        t = time.perf_counter()
        res = train(data, name, args.out / name, epochs=epochs, warmup_epochs=warmup, max_samples=samples,
                    max_val_samples=2000, seed=0, progress=False)
        train_s[name] = time.perf_counter() - t
        pred = ModelPredictor.from_run(args.out / name)
        results[name] = evaluate(data, pred, "traphic", split="test", progress=False, name=name)
        curves[name] = results[name]["rmse_per_second"]
        print(f"{name}: trained {train_s[name]:.0f} s ({res['samples_per_s']:.0f} samples/s), best epoch "
              f"{res['best_epoch']}")
    results["const-vel"] = evaluate(data, ConstantVelocity(), "traphic", split="test", progress=False,
                                    name="const-vel")
    curves["const-vel"] = results["const-vel"]["rmse_per_second"]
    print(f"\naccuracy on the held-out scenes of {data} ({'full' if args.full else 'quick'} budget: "
          f"{samples or 'all'} windows x {epochs} epochs):")
    print(format_table(results))
    print("RMSE per horizon second (m): " + "; ".join(
        f"{k} " + " ".join(f"{v:.2f}" for v in c) for k, c in curves.items()))
    order = sorted(VARIANTS, key=lambda k: results[k]["ade_rmse"])
    print(f"ablation order, best to worst by ADE-RMSE: {' < '.join(order)} (paper: traphic < traphic-ho < "
          "traphic-he < traphic-b)")
    fig = plot_rmse_curve(curves, args.out / "rmse_curve.png", title="RMSE per horizon second, dense arterial")
    (args.out / "results.json").write_text(json.dumps({"speed": timing, "results": results,
                                                       "train_seconds": train_s}, indent=1) + "\n")
    print(f"-> {fig}, {args.out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
