"""Real-data figures on the samples (../shared/data), measured end to end with `simharness` commands.

    python bench/real_goals.py                              # all five parts, 2 seeds (about 30 min on 2 shared cores)
    python bench/real_goals.py --parts traf,sim2real --reuse  # some parts; keep finished runs

Parts (each prints a markdown table; the numbers in docs/results.md (open loop, real data) come from here):
- eth: ETH/UCY leave-one-scene-out over the scenes in ../shared/data/eth_ucy, each fold laid out as Social-GAN
  does (test/<held>.txt; train/<other>_train.txt and val/<other>_val.txt, the first 80% / last 20% of each other
  scene's lines), so training validates on the `*_val` files; TraPHic vs constant velocity, `eth-ucy` protocol.
- eth-halves: the same with each scene cut in two halves in time (SCENE_a, SCENE_b), one half held out per fold,
  so that every fold trains on a scene of the held-out one's kind, as the five-scene split does (a proxy for it:
  the halves share a place and a camera).
- traf: every TRAF video (imported with --type-default car --pixel-scale 0.03), two disjoint groups of videos,
  trained on one and scored on the other, both directions; TraPHic vs CS-LSTM vs constant velocity.
- apollo: ApolloScape sample, split by scene hash; TraPHic vs constant velocity with the `apolloscape` protocol.
- sim2real: the TRAF folds again, TraPHic in the paper's form fine-tuned from the shipped weights (trained on
  `simharness generate` SUMO data; `train --init shipped`) vs the same model trained on the real videos alone;
  with `--init RUN`, a residual TraPHic pre-trained on generated data (run folder RUN) instead, both arms residual.
- sim2real-eth, sim2real-eth-halves (not in the default parts): the eth / eth-halves folds with TraPHic fine-tuned
  from `--init-eth RUN`, a residual TraPHic trained on generated data with eth-ucy windows, against the eth part's
  runs (the same budget from scratch). The pre-training needs re-annotated copies (`simharness train` makes none
  on generated data unless asked):
      simharness train --data SUMO_DATA --protocol eth-ucy --epochs 8 --max-samples 30000 \
          --reannotate-smooth 0.5 --reannotate-noise 0.1 --out runs/syn_eth
      python bench/real_goals.py --parts sim2real-eth,sim2real-eth-halves --init-eth runs/syn_eth

The eth, eth-halves and traf tables also score `const-vel:5` (the mean velocity over the last 5 observed steps), a
smoothed reference beside the plain constant velocity that the goals name.

Scores are per held-out scene (`simharness.evaluation.evaluate`, the code behind `simharness evaluate`), so that a
difference between two methods gets a 95% bootstrap CI over test scenes (paired, seeds averaged per scene).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the project's `predictor` package, not bench/predictor.py beside this file
SHARED = ROOT.parent / "shared" / "data"

from simharness.io.folders import is_dataset_folder  # noqa: E402

# Two disjoint groups of TRAF videos; the three TRAF53 parts (one video) stay together.
TRAF_A = ["TRAF11", "TRAF13", "TRAF15", "TRAF21", "TRAF23", "TRAF26", "TRAF37", "TRAF53_1", "TRAF53_2", "TRAF53_3"]
TRAF_B = ["TRAF12", "TRAF17", "TRAF18", "TRAF22", "TRAF25", "TRAF27", "TRAF38"]
LABEL = {"const-vel": "Constant velocity", "const-vel:5": "Constant velocity over the last 5 steps",
         "traphic": "TraPHic", "cs-lstm": "CS-LSTM",
         "traphic-init": "TraPHic, pre-trained on synthetic + fine-tuned", "traphic-scratch": "TraPHic, real data only",
         "traphic-b": "TraPHic-B (no neighbours)", "traphic-he": "TraPHic-He", "traphic-ho": "TraPHic-Ho"}


def sh(*args: str) -> None:
    """Run `simharness ARGS` (printed first); stops the benchmark on failure."""
    print("$ " + shlex.join(["simharness", *args]), file=sys.stderr, flush=True)
    subprocess.run([sys.executable, "-m", "simharness", *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL,
                   env={**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)})


def per_scene(data: Path, model: str, protocol: str, scenes: list[str]) -> dict[str, dict]:
    """{scene: metrics} of `model` (run folder or const-vel) on each held-out scene in turn."""
    from simharness.evaluation import evaluate
    from simharness.predictors import load_predictor

    pred = load_predictor(model)
    return {s: evaluate(data, pred, protocol, split="test", test_scenes=[s], progress=False) for s in scenes}


def pooled(scores: dict[str, dict], key: str) -> float:
    """Sample-weighted mean over scenes (RMSE keys pooled as root of the weighted mean square)."""
    n = np.array([m["samples"] for m in scores.values()], float)
    v = np.array([m[key] for m in scores.values()], float)
    return float(np.sqrt((n * v ** 2).sum() / n.sum())) if "rmse" in key else float((n * v).sum() / n.sum())


def paired_ci(a: list[dict[str, dict]], b: list[dict[str, dict]], key: str, reps: int = 2000) -> tuple[float, ...]:
    """Relative difference (a - b) / b of the pooled `key`, seeds averaged per scene, with a 95% bootstrap CI over
    scenes -> (difference, low, high)."""
    scenes = sorted(a[0])
    n = np.array([a[0][s]["samples"] for s in scenes], float)
    va = np.array([[r[s][key] for s in scenes] for r in a]).mean(0)
    vb = np.array([[r[s][key] for s in scenes] for r in b]).mean(0)
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(scenes), (reps, len(scenes)))
    rel = lambda i: (n[i] * va[i]).sum(-1) / (n[i] * vb[i]).sum(-1) - 1  # noqa: E731
    boot = rel(idx)
    return float(rel(np.arange(len(scenes)))), float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))


def train_all(jobs: list[tuple[Path, list[str]]], reuse: bool, parallel: int) -> None:
    """Train each (run folder, args) not already done (--reuse), `parallel` at a time."""
    todo = [(run, args) for run, args in jobs if not (reuse and (run / "config.json").is_file())]
    # The first run of each data set and window length alone: it builds the windows cache the others read.
    first: dict[str, tuple[Path, list[str]]] = {}
    for run, args in todo:
        first.setdefault(" ".join(a for a in args if a.startswith(("/", "eth-ucy", "apolloscape"))), (run, args))
    for run, args in first.values():
        sh("train", *args, "--out", str(run))
    rest = [j for j in todo if all(j[0] != f[0] for f in first.values())]
    with cf.ThreadPoolExecutor(parallel) as ex:
        for f in [ex.submit(sh, "train", *args, "--out", str(run)) for run, args in rest]:
            f.result()


def fmt(x: float, d: int = 2) -> str:
    return f"{x:.{d}f}"


def table(title: str, units: str, folds: dict[str, dict[str, list[dict]]], ref: str) -> str:
    """folds: fold name -> method -> per-seed per-scene scores. Rows per fold and method, with the relative ADE/FDE
    against `ref` and its CI."""
    out = [f"**{title}** ({units})", "",
           f"| Fold (held out) | Method | ADE / FDE (mean Euclidean) | ADE / FDE (RMSE) | test windows | "
           f"ADE vs {LABEL[ref]} (95% CI over scenes) | FDE vs {LABEL[ref]} |", "|---|---|---|---|---|---|---|"]
    avg: dict[str, list[tuple[float, float]]] = {}
    for fold, methods in folds.items():
        for m, runs in methods.items():
            ade = np.mean([pooled(r, "ade") for r in runs])
            fde = np.mean([pooled(r, "fde") for r in runs])
            ar = np.mean([pooled(r, "ade_rmse") for r in runs])
            fr = np.mean([pooled(r, "fde_rmse") for r in runs])
            avg.setdefault(m, []).append((ade, fde))
            n = sum(s["samples"] for s in runs[0].values())
            rel = "-"
            if m != ref and ref in methods:
                d, lo, hi = paired_ci(runs, methods[ref], "ade")
                e, elo, ehi = paired_ci(runs, methods[ref], "fde")
                rel = (f"{d:+.0%} [{lo:+.0%}, {hi:+.0%}] | {e:+.0%} [{elo:+.0%}, {ehi:+.0%}]" if len(runs[0]) > 1
                       else f"{d:+.0%} | {e:+.0%}")
            else:
                rel = "- | -" if m == ref else "n/a | n/a"
            seeds = f" ({len(runs)} seeds)" if len(runs) > 1 else ""
            out.append(f"| {fold} | {LABEL[m]}{seeds} | {fmt(ade)} / {fmt(fde)} | {fmt(ar)} / {fmt(fr)} | {n} "
                       f"| {rel} |")
    if len(folds) > 1:
        for m, v in avg.items():
            a = np.mean(v, 0)
            out.append(f"| average of folds | {LABEL[m]} | {fmt(a[0])} / {fmt(a[1])} | | | | |")
    return "\n".join(out)


def prepare(args: argparse.Namespace) -> dict[str, Path]:
    """Import the real samples (and build the ETH/UCY folds); returns the data set folders."""
    d = args.data
    paths = {"traf": d / "traf", "apollo": d / "apollo"}
    if not is_dataset_folder(d / "traf"):
        sh("import", "traf", str(SHARED / "traf"), "--out", str(d / "traf"), "--type-default", "car",
           "--pixel-scale", "0.03")
    if not is_dataset_folder(d / "apollo"):
        sh("import", "apolloscape", str(SHARED / "apolloscape"), "--out", str(d / "apollo"))
    whole = {p.stem: p.read_text().splitlines(keepends=True) for p in sorted((SHARED / "eth_ucy").glob("*.txt"))}
    for part, scenes in (("eth", whole), ("eth-halves", halves(whole))):
        for held in scenes:
            src, out = d / f"{part}-src" / held, d / f"{part}-not-{held}"
            paths[f"{part}:{held}"] = out
            if is_dataset_folder(out):
                continue
            for sub in ("train", "val", "test"):
                (src / sub).mkdir(parents=True, exist_ok=True)
            (src / "test" / f"{held}.txt").write_text("".join(scenes[held]))
            for other, lines in scenes.items():
                if other != held:
                    cut = int(len(lines) * 0.8)
                    (src / "train" / f"{other}_train.txt").write_text("".join(lines[:cut]))
                    (src / "val" / f"{other}_val.txt").write_text("".join(lines[cut:]))
            sh("import", "eth-ucy", str(src / "train"), str(src / "val"), str(src / "test"), "--out", str(out))
    return paths


def halves(scenes: dict[str, list[str]]) -> dict[str, list[str]]:
    """Each ETH/UCY scene's lines cut at its median frame into SCENE_a and SCENE_b: leaving one half out, every
    fold still trains on a scene of its kind (annotation, place), as the five-scene split does (eth for hotel,
    univ and zara02 for zara01), which leaving one of only two whole scenes out cannot show."""
    out = {}
    for name, lines in scenes.items():
        mid = np.median([float(line.split()[0]) for line in lines])
        out[f"{name}_a"] = [line for line in lines if float(line.split()[0]) < mid]
        out[f"{name}_b"] = [line for line in lines if float(line.split()[0]) >= mid]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="eth,eth-halves,traf,apollo,sim2real")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--epochs", type=int, default=6)
    ap.add_argument("--warmup-epochs", type=int, default=2)
    ap.add_argument("--max-samples", type=int, default=3000)
    ap.add_argument("--parallel", type=int, default=2, help="training processes at once")
    ap.add_argument("--data", type=Path, default=ROOT / "data" / "real14")
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "real14")
    ap.add_argument("--reuse", action="store_true")
    ap.add_argument("--init", default="shipped",
                    help="sim2real's pre-trained weights: shipped (the paper's form, as shipped) or a run folder of a "
                         "residual TraPHic trained on `simharness generate` data (then both arms are residual)")
    ap.add_argument("--init-eth", default=None,
                    help="sim2real-eth(-halves)' pre-trained weights: a run folder of a residual TraPHic trained on "
                         "generated data with --protocol eth-ucy")
    ap.add_argument("--train-args", default="", help="more `simharness train` options for every run, e.g. '--augment'")
    ap.add_argument("--traf-models", default="traphic,cs-lstm", help="models trained on TRAF (`train --model`)")
    ap.add_argument("--score-only", action="store_true", help="train nothing; score the runs already finished")
    args = ap.parse_args()
    parts = args.parts.split(",")
    if any(p.startswith("sim2real-eth") for p in parts) and not args.init_eth:
        ap.error("the sim2real-eth parts need --init-eth RUN (pre-trained on generated data with --protocol eth-ucy)")
    seeds = [int(s) for s in args.seeds.split(",")]
    budget = ["--epochs", str(args.epochs), "--warmup-epochs", str(args.warmup_epochs),
              "--max-samples", str(args.max_samples), *shlex.split(args.train_args)]
    paths = prepare(args)
    t0 = time.perf_counter()
    traf_folds = {"A->B": (TRAF_A, TRAF_B), "B->A": (TRAF_B, TRAF_A)}
    from simharness.io.parquet import Dataset

    traf_ids = Dataset(paths["traf"]).scene_ids
    held_ids = {k: [i for i in traf_ids if i.removesuffix("_gt") in test] for k, (_, test) in traf_folds.items()}
    jobs: list[tuple[Path, list[str]]] = []
    plan: dict[str, dict[str, dict[str, list[Path]]]] = {}  # part -> fold -> method -> runs
    for seed in seeds:
        s = ["--seed", str(seed)]
        for key, data in paths.items():
            part, _, held = key.partition(":")
            if part in ("eth", "eth-halves") and {part, f"sim2real-{part}"} & set(parts):
                run = args.out / part / f"traphic-not-{held}-s{seed}"
                jobs.append((run, ["--data", str(data), "--protocol", "eth-ucy", *budget, *s]))
                if part in parts:
                    plan.setdefault(part, {}).setdefault(held, {}).setdefault("traphic", []).append(run)
                if f"sim2real-{part}" in parts:  # the run above is the arm from scratch
                    init = args.out / f"sim2real-{part}" / f"traphic-init-not-{held}-s{seed}"
                    jobs.append((init, ["--data", str(data), "--protocol", "eth-ucy", "--init", args.init_eth,
                                        *budget, *s]))
                    arms = plan.setdefault(f"sim2real-{part}", {}).setdefault(held, {})
                    arms.setdefault("traphic-init", []).append(init)
                    arms.setdefault("traphic-scratch", []).append(run)
        for fold, (_, test) in traf_folds.items():
            held = ["--test-scenes", ",".join(t + "_gt" for t in test)]
            tag = fold.replace("->", "to")
            if "traf" in parts:
                for model in args.traf_models.split(","):
                    run = args.out / "traf" / f"{model}-{tag}-s{seed}"
                    jobs.append((run, ["--data", str(paths["traf"]), "--model", model, *held, *budget, *s]))
                    plan.setdefault("traf", {}).setdefault(fold, {}).setdefault(model, []).append(run)
            if "sim2real" in parts:
                form = ["--no-residual"] if args.init == "shipped" else []
                for name, init in (("traphic-init", ["--init", args.init]), ("traphic-scratch", [])):
                    run = args.out / "sim2real" / f"{name}-{tag}-s{seed}"
                    jobs.append((run, ["--data", str(paths["traf"]), *form, *init, *held, *budget, *s]))
                    plan.setdefault("sim2real", {}).setdefault(fold, {}).setdefault(name, []).append(run)
        if "apollo" in parts:
            run = args.out / "apollo" / f"traphic-s{seed}"
            jobs.append((run, ["--data", str(paths["apollo"]), "--protocol", "apolloscape", *budget, *s]))
            plan.setdefault("apollo", {}).setdefault("hash split", {}).setdefault("traphic", []).append(run)
    if args.score_only:  # keep finished runs only (config.json is written last)
        for folds in plan.values():
            for fold, methods in folds.items():
                folds[fold] = {m: [r for r in runs if (r / "config.json").is_file()] for m, runs in methods.items()}
                folds[fold] = {m: runs for m, runs in folds[fold].items() if runs}
        jobs = []
    train_all(jobs, args.reuse, args.parallel)
    train_s = time.perf_counter() - t0
    from predictor.split import split_scenes

    for part, folds in plan.items():
        eth = part.removeprefix("sim2real-")
        protocol = "eth-ucy" if eth in ("eth", "eth-halves") else "apolloscape" if part == "apollo" else "traphic"
        scored: dict[str, dict[str, list[dict]]] = {}
        for fold, methods in folds.items():
            data = paths.get(f"{eth}:{fold}") or paths["apollo" if part == "apollo" else "traf"]
            ids = Dataset(data).scene_ids
            test = held_ids[fold] if part in ("traf", "sim2real") else split_scenes(ids)["test"]
            scored[fold] = {m: [per_scene(data, str(r), protocol, test) for r in runs] for m, runs in methods.items()}
            scored[fold]["const-vel"] = [per_scene(data, "const-vel", protocol, test)]
            if part in ("eth", "eth-halves", "traf"):  # the smoothed reference: what the learned blend of lags reaches
                scored[fold]["const-vel:5"] = [per_scene(data, "const-vel:5", protocol, test)]
        ref = "traphic-scratch" if part.startswith("sim2real") else "const-vel"
        units = "px" if part in ("traf", "sim2real") else "m"
        print(f"\n{table(f'{part}: protocol {protocol}', units, scored, ref)}\n", flush=True)
        (args.out / f"{part}.json").write_text(json.dumps(scored, indent=0))
    print(f"training wall time {train_s:.0f} s for {len(jobs)} runs, total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
