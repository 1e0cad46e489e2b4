"""TraPHic and constant velocity on the real samples (../shared/data): TRAF in pixels, ETH/UCY in metres.

    python bench/real_data.py                  # import, train (a few CPU minutes per model), evaluate, tabulate
    python bench/real_data.py --reuse          # keep run folders already trained with the same settings

Every step is a `simharness` command, printed before it runs, so the tables in docs/results.md ("Real
data") can be remade by hand. Splits are leave-one-scene-out both ways: TRAF11 against TRAF12 with the
`traphic` protocol (3 s + 5 s at 5 Hz), biwi_hotel against crowds_zara01 with `eth-ucy` (8 + 12 frames at
2.5 Hz). Prints markdown tables (ADE/FDE as RMSE and as mean Euclidean error, NLL, samples, training
seconds) and writes the RMSE-per-second figures.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
TRAF = {"protocol": "traphic", "train": ["--epochs", "30", "--warmup-epochs", "5", "--max-samples", "4000"],
        "folds": [("TRAF11_gt", "TRAF12_gt"), ("TRAF12_gt", "TRAF11_gt")],
        "extra": [("TraPHic, shipped", "traphic")]}  # the weights trained on synthetic SUMO data, zero-shot
ETH = {"protocol": "eth-ucy", "train": ["--protocol", "eth-ucy", "--epochs", "100", "--warmup-epochs", "10"],
       "folds": [("crowds_zara01", "biwi_hotel"), ("biwi_hotel", "crowds_zara01")]}


def sh(*args: str) -> float:
    """Run `simharness ARGS` (printed first) -> wall seconds; stops the benchmark on failure."""
    cmd = ["simharness", *args]
    print("$ " + shlex.join(cmd), file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "simharness", *args], check=True, cwd=ROOT,
                   env={**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")})
    return time.perf_counter() - t0


def trained(run: Path, data: Path, held: str, settings: list[str]) -> bool:
    """A run folder from an earlier call with the same data, held-out scene and epochs."""
    cfg_path = run / "config.json"
    if not cfg_path.is_file():
        return False
    cfg = json.loads(cfg_path.read_text())
    epochs = int(settings[settings.index("--epochs") + 1])
    return cfg["split"]["test"] == [held] and cfg["train"]["epochs"] == epochs and Path(cfg["data"]) == data


def train_seconds(run: Path) -> float:
    """Seconds spent in the training loop (log.csv, per epoch; window building and validation excluded)."""
    lines = (run / "log.csv").read_text().splitlines()
    col = lines[0].split(",").index("seconds")
    return sum(float(line.split(",")[col]) for line in lines[1:])


def run_set(name: str, spec: dict, data: Path, out: Path, reuse: bool) -> list[dict]:
    rows = []
    for train_on, held in spec["folds"]:
        run = out / f"traphic-{name}-not-{held}"
        if not (reuse and trained(run, data, held, spec["train"])):
            sh("train", "--data", str(data), "--model", "traphic", "--test-scenes", held, "--seed", "0",
               *spec["train"], "--out", str(run))
        secs = train_seconds(run)
        for method, model in (("TraPHic", str(run)), ("Constant velocity", "const-vel"), *spec.get("extra", [])):
            slug = {"TraPHic": "traphic", "Constant velocity": "const-vel"}.get(method, "traphic-shipped")
            ev = out / "eval" / f"{slug}-{name}-{held}"
            sh("evaluate", "--data", str(data), "--model", model, "--protocol", spec["protocol"], "--test-scenes",
               held, "--out", str(ev))
            m = json.loads((ev / "metrics.json").read_text())
            train_on_label = {"TraPHic": train_on, "TraPHic, shipped": "synthetic (SUMO)"}.get(method, "-")
            rows.append({"method": method, "train": train_on_label, "test": held,
                         "train_s": secs if method == "TraPHic" else None, **m})
    return rows


def table(rows: list[dict], units: str) -> str:
    f = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    out = [f"| Method | Trained on | Tested on | ADE/FDE (RMSE, {units}) | ADE/FDE (mean Euclidean, {units}) | "
           f"NLL (nats) | Test samples | Training loop (s) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t = "-" if r["train_s"] is None else f"{r['train_s']:.0f}"
        out.append(f"| {r['method']} | {r['train']} | {r['test']} | {f(r['ade_rmse'])}/{f(r['fde_rmse'])} | "
                   f"{f(r['ade'])}/{f(r['fde'])} | {f(r.get('nll'))} | {r['samples']} | {t} |")
    for method in dict.fromkeys(r["method"] for r in rows):  # the per-scene mean, as ETH/UCY tables average scenes
        mine = [r for r in rows if r["method"] == method]
        avg = {k: sum(r[k] for r in mine) / len(mine) for k in ("ade_rmse", "fde_rmse", "ade", "fde")}
        out.append(f"| {method}, mean of the two | | | {f(avg['ade_rmse'])}/{f(avg['fde_rmse'])} | "
                   f"{f(avg['ade'])}/{f(avg['fde'])} | | | |")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("data/real"), help="where the imported data sets go")
    ap.add_argument("--out", type=Path, default=Path("runs/real"), help="run folders and evaluations")
    ap.add_argument("--figures", type=Path, default=Path("docs/figures/real"))
    ap.add_argument("--reuse", action="store_true", help="keep run folders trained with the same settings")
    args = ap.parse_args()
    from simharness.report import plot_rmse_curve

    traf, eth = args.data / "traf", args.data / "eth_ucy"
    for fmt, src, dst in (("traf", "traf", traf), ("eth-ucy", "eth_ucy", eth)):
        if not (args.reuse and (dst / "_manifest.json").is_file()):
            sh("import", fmt, str(SHARED / src), "--out", str(dst))
    for name, spec, data, units in (("traf", TRAF, traf, "px"), ("eth", ETH, eth, "m")):
        rows = run_set(name, spec, data, args.out, args.reuse)
        print(f"\n{name}: protocol {spec['protocol']}, units {units}\n\n{table(rows, units)}\n")
        print("RMSE per horizon second:")
        for r in rows:
            print(f"  {r['method']:<18} test {r['test']:<14} " + ", ".join(f"{v:.2f}" for v in r["rmse_per_second"]))
        for held in dict.fromkeys(r["test"] for r in rows):
            curves = {r["method"]: r["rmse_per_second"] for r in rows if r["test"] == held}
            path = plot_rmse_curve(curves, ROOT / args.figures / f"{name}_{held}_rmse.png", units=units,
                                   title=f"{held} held out ({spec['protocol']} protocol)")
            print(f"  -> {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
