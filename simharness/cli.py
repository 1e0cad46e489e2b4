"""Command line: argument parsing only; each command calls one function elsewhere.

Bad input (`UserError`) prints one line `simharness: error: ...` and exits 2.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from simharness.errors import SimulatorError, UserError

MAX_SEED = 2**31 - 1  # simulators take 32-bit signed seeds
MAX_SEEDS = 1_000_000  # per command: more is a typo, and would fill memory before anything ran


def cv_lags(text: str) -> str | int:
    """`--cv-lags`: "auto" or a whole number of steps from 1."""
    if text == "auto":
        return text
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected auto or a whole number from 1, got {text!r}")
    return int(text)


def parse_seeds(text: str) -> list[int]:
    """"0-99" or "1,5,9" or "3" or mixes ("0-4,10") -> sorted unique ints in [0, 2^31-1], at most 1e6 of them.

    Bounds are checked on the parsed ends before any list is built, so "0-99999999999" fails at once.
    """
    spans: list[tuple[int, int]] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part[1:]:
                lo, hi = part.split("-", 1)
                spans.append((int(lo), int(hi)))
            else:
                spans.append((int(part), int(part)))
            if spans[-1][1] < spans[-1][0]:
                raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad seed list {text!r}; expected e.g. 0-99 or 1,5,9") from None
    if min(lo for lo, _ in spans) < 0 or max(hi for _, hi in spans) > MAX_SEED:
        raise argparse.ArgumentTypeError(f"bad seed list {text!r}; seeds must be in 0..{MAX_SEED}")
    if sum(hi - lo + 1 for lo, hi in spans) > MAX_SEEDS:
        raise argparse.ArgumentTypeError(f"bad seed list {text!r}; at most {MAX_SEEDS:,} seeds per command")
    seeds: set[int] = set()
    for lo, hi in spans:
        seeds.update(range(lo, hi + 1))
    return sorted(seeds)


def finite_float(text: str) -> float:
    """A float option that refuses NaN and infinities (float() accepts "nan", "inf", "1e999")."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def parse_set(text: str) -> tuple[str, list[str]]:
    """"demand_scale=0.5,1,2" -> ("demand_scale", ["0.5", "1", "2"])."""
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"bad --set {text!r}; expected KEY=V1,V2,...")
    key, values = text.split("=", 1)
    return key.strip(), [v.strip() for v in values.split(",") if v.strip()]


def parse_names(text: str) -> list[str]:
    """"hotel" or "TRAF11,TRAF12" -> ["hotel"] / ["TRAF11", "TRAF12"]."""
    names = [v.strip() for v in text.split(",") if v.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"bad scene list {text!r}; expected e.g. hotel or zara01,hotel")
    return names


def float_list(text: str) -> list[float]:
    """"0.5" or "0.05,0.15" -> [0.5] / [0.05, 0.15]."""
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad list of numbers {text!r}; expected e.g. 0.1 or 0.05,0.15") from None


def _call(target: str) -> Callable[[argparse.Namespace], int | None]:
    """Lazy 'module:function' so that `simharness --help` does not import torch or SUMO."""
    module, func = target.split(":")

    def run(args: argparse.Namespace) -> int | None:
        return getattr(importlib.import_module(module), func)(args)

    return run


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="simharness", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"simharness {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def cmd(name: str, target: str, help: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help, description=help)
        sp.set_defaults(func=_call(target))
        return sp

    executor_args = argparse.ArgumentParser(add_help=False)
    executor_args.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    executor_args.add_argument("--executor", choices=["local", "ray"], default="local")
    executor_args.add_argument("--address", default=None, help="Ray cluster address (with --executor ray)")

    force_help = "write into a non-empty --out folder (files of the same name are replaced)"

    def force(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--force", action="store_true", help=force_help)

    g = sub.add_parser("generate", parents=[executor_args], help="simulate a scenario over seeds into a data set")
    g.set_defaults(func=_call("simharness.generation:generate_command"))
    g.add_argument("scenario", help="scenario file, or a shipped scenario's name")
    g.add_argument("--seeds", type=parse_seeds, default=[0], help="e.g. 0-99 (default 0)")
    g.add_argument("--out", type=Path, required=True, help="data set folder")
    g.add_argument("--duration", type=finite_float, default=None, help="override recorded seconds per scene")

    s = cmd("stats", "simharness.stats:stats_command", "a data set's figures (the TraPHic paper's Table 1)")
    s.add_argument("data", type=Path)
    s.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    s.add_argument("--figure", type=Path, default=None, help="write a top-down frame figure (PNG)")

    t = cmd("train", "predictor.train:train_command", "train a predictor on a data set")
    t.add_argument("--data", type=Path, required=True)
    t.add_argument("--model", default="traphic", help="traphic, traphic-b, traphic-he, traphic-ho, or a baseline")
    t.add_argument("--out", type=Path, required=True, help="run folder (checkpoint, config, log)")
    force(t)
    t.add_argument("--epochs", type=int, default=16)
    t.add_argument("--warmup-epochs", type=int, default=2, help="MSE epochs before the NLL")
    t.add_argument("--batch-size", type=int, default=128)
    t.add_argument("--lr", type=finite_float, default=1e-3)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--max-samples", type=int, default=None, help="cap training windows (quick runs)")
    t.add_argument("--test-scenes", type=parse_names, default=None,
                   help="hold these scenes out (leave-one-scene-out), e.g. hotel; default: a split by scene hash")
    t.add_argument("--init", default=None, metavar="RUN|shipped",
                   help="fine-tune: start from a run folder's weights or the shipped ones (same model config)")
    t.add_argument("--protocol", default=None,
                   help="train on this evaluation protocol's windows (eth-ucy: 8 + 12 frames at 2.5 Hz; "
                        "apolloscape: 3 + 3 at 2 Hz); "
                        "default 3 s + 5 s at 5 Hz")
    t.add_argument("--lr-schedule", choices=["cosine", "plateau", "constant"], default="cosine",
                   help="cosine decay after a linear warm-up (default), halve on a validation plateau, or constant")
    t.add_argument("--patience", type=int, default=3,
                   help="stop after this many epochs (after the warm-up) without a better validation score (--select; "
                        "default 3; the best epoch's weights are kept)")
    t.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="auto (default): CUDA when torch sees a GPU, else the CPU")
    t.add_argument("--mean-loss", choices=["nll", "mse", "ade"], default="ade",
                   help="ade (default) fits the means by the mean Euclidean error, warm-up included (robust to the "
                        "huge misses of real tracks) while sigma and rho follow the Gaussian NLL after the warm-up; "
                        "mse likewise by the squared error; nll trains the means by the NLL too (the paper)")
    t.add_argument("--residual", action=argparse.BooleanOptionalAction, default=True,
                   help="predict a correction to constant-velocity extrapolation (default) or, with --no-residual, "
                        "the means directly as in the paper")
    t.add_argument("--cv-lags", type=cv_lags, default="auto",
                   help="residual form: extrapolate from the last displacement (1) plus a learned blend of the mean "
                        "displacements over up to N steps (jittery tracks; not Social-GAN); auto (default): 5 with "
                        "--cv-gate, else the lag whose constant velocity fits the training windows best, up to 5")
    t.add_argument("--cv-gate", action=argparse.BooleanOptionalAction, default=True,
                   help="residual form: the blend of lags is learned per track from its own jitter (default; smooth "
                        "the tracks whose noise is in the annotation, extrapolate the steady turns of clean ones), "
                        "with --cv-lags auto every lag up to 5 offered; --no-cv-gate: one blend for all tracks; with "
                        "--init, as the run it fine-tunes")
    t.add_argument("--cv-gate-pool", action=argparse.BooleanOptionalAction, default=True,
                   help="with --cv-gate: the gate reads the jitter pooled over the target and the agents in its "
                        "neighbour and horizon slots (default: annotation noise is the recording's); "
                        "--no-cv-gate-pool: the target's own track only; with --init, as the run it fine-tunes")
    t.add_argument("--select", choices=["loss", "mse", "ade"], default="ade",
                   help="the validation criterion that picks the checkpoint: ade (default) / mse, the means' Euclidean "
                        "/ squared error over the epochs after the warm-up (whose sigma, which planners read, is "
                        "fitted) and the --init run's weights; or loss, the epoch's own loss (MSE in the warm-up, "
                        "then NLL)")
    t.add_argument("--augment", action=argparse.BooleanOptionalAction, default=True,
                   help="mirror a random half of every batch left-right (default on; --no-augment)")
    t.add_argument("--scale-jitter", type=float, default=0.0, metavar="J",
                   help="scale every training sample (positions, velocities, sizes, future) by a random factor "
                        "in [1/(1+J), 1+J]: robust to a video's unknown pixel scale or a scene's walking speed "
                        "(default 0: off)")
    t.add_argument("--reannotate-smooth", type=float_list, default=None, metavar="S[,S...]",
                   help="copy every training scene with each track smoothed along time over S seconds (a Gaussian-"
                        "weighted local line; 0: none). With --reannotate-noise, the residual form's gate sees each "
                        "recording at several annotation noise levels, and carries over to recordings annotated "
                        "otherwise (ETH/UCY scene to scene, TRAF video to video). Default: 0.5 for recorded data in "
                        "the gated residual form; none for `simharness generate` output (exact positions) or "
                        "--no-residual / --no-cv-gate (no gate to read the noise level)")
    t.add_argument("--reannotate-noise", type=float_list, default=None, metavar="M[,M...]",
                   help="copy every training scene with white noise of std M metres added to every position (0: "
                        "none; default: 0.1 where --reannotate-smooth defaults to 0.5, else none). Each training "
                        "sample is drawn from its scene or a copy, anew every epoch; validation stays on the scenes "
                        "as recorded")

    e = cmd("evaluate", "simharness.evaluation:evaluate_command", "score a predictor open-loop on a data set")
    e.add_argument("--data", type=Path, required=True)
    e.add_argument("--model", required=True, help="a run folder, 'traphic' (shipped weights), 'const-vel' or "
                   "'const-vel:N' (the mean velocity over the last N history steps)")
    e.add_argument("--out", type=Path, default=None, help="folder for metrics.json and figures")
    force(e)
    e.add_argument("--protocol", default="traphic",
                   help="traphic (3 s / 5 s), eth-ucy (8 / 12 frames at 2.5 Hz) or apolloscape (3 / 3 frames at 2 Hz)")
    e.add_argument("--split", default="test", choices=["test", "all"], help="held-out scenes or every scene")
    e.add_argument("--test-scenes", type=parse_names, default=None,
                   help="the scenes held out in training (leave-one-scene-out), e.g. hotel")

    c = sub.add_parser("closedloop", parents=[executor_args], help="drive an ego on a predictor's forecasts")
    c.set_defaults(func=_call("simharness.closedloop:closedloop_command"))
    c.add_argument("scenario")
    c.add_argument("--predictor", default="traphic", help="traphic, const-vel, oracle, none, or a run folder")
    c.add_argument("--seeds", type=parse_seeds, default=[0])
    c.add_argument("--out", type=Path, default=Path("runs/closedloop"))
    force(c)
    c.add_argument("--animate", type=int, default=0, help="write an animation for the first N episodes")
    c.add_argument("--reaction", default=None, choices=["reactive", "cut_in", "ignore"],
                   help="override how background agents treat the ego")

    b = sub.add_parser("benchmark", parents=[executor_args], help="train and compare every method (paper tables)")
    b.set_defaults(func=_call("simharness.benchmark:benchmark_command"))
    b.add_argument("--data", type=Path, required=True)
    b.add_argument("--profile", choices=["quick", "medium", "full"], default="quick",
                   help="training budget: quick (tests), medium (~10-15 CPU-minutes), full (16 epochs, early "
                        "stopping, at most 80,000 windows: within 3 hours on 2 cores)")
    b.add_argument("--out", type=Path, default=Path("runs/benchmark"))
    force(b)
    b.add_argument("--residual", action=argparse.BooleanOptionalAction, default=True,
                   help="train every method in the residual form (default) or the paper's (--no-residual)")
    b.add_argument("--protocol", default="traphic",
                   help="evaluation protocol (training windows of its length and rate): traphic, eth-ucy, apolloscape")

    i = cmd("import", "simharness.io.importers:import_command", "convert a public data set into ours")
    i.add_argument("format", help="eth-ucy, traf, apolloscape, commonroad, argoverse2, tracknpred")
    i.add_argument("src", type=Path, nargs="+", help="source file(s) or folder")
    i.add_argument("--out", type=Path, required=True)
    i.add_argument("--allow-pickle", action="store_true", help="allow reading pickled .npy files you trust")
    i.add_argument("--type-default", default=None, metavar="TYPE",
                   help="traf: class of ids that are bare numbers (no class in the file), e.g. car; default other")
    i.add_argument("--pixel-scale", type=float, default=None, metavar="M_PER_PX",
                   help="traf: metres per pixel for videos without cars to estimate it from, e.g. 0.03")
    i.add_argument("--fps", type=float, default=None, help="traf: video frame rate (default 20, the data set's)")
    i.add_argument("--image-size", default=None, metavar="WxH",
                   help="traf: video frame size in pixels (default: from the boxes' extent)")

    x = cmd("export", "simharness.io.exporters:export_command", "write a data set in another tool's layout")
    x.add_argument("format", help="tracknpred")
    x.add_argument("data", type=Path)
    x.add_argument("--out", type=Path, required=True)

    w = sub.add_parser("sweep", parents=[executor_args], help="closed loop over a grid of scenario settings")
    w.set_defaults(func=_call("simharness.sweep:sweep_command"))
    w.add_argument("scenario")
    w.add_argument("--set", dest="sets", type=parse_set, action="append", default=[],
                   help="KEY=V1,V2,... (repeatable), e.g. demand_scale=0.5,1,2")
    w.add_argument("--predictor", default="traphic")
    w.add_argument("--seeds", type=parse_seeds, default=[0])
    w.add_argument("--out", type=Path, default=Path("runs/sweep"))
    force(w)

    se = sub.add_parser("sensitivity", parents=[executor_args],
                        help="closed loop over a grid of forecast perturbations (what prediction error costs)")
    se.set_defaults(func=_call("simharness.closedloop.sensitivity:sensitivity_command"))
    se.add_argument("scenario", help="scenario file, or a shipped name (stress/step_out)")
    se.add_argument("--predictor", default="oracle", help="oracle (default), static, const-vel, traphic, a run folder")
    se.add_argument("--perturb", action="append", default=[],
                    help="KEY=V1,V2,... (repeatable: a grid), keys noise (m), latency (frames), speed (x), "
                         "heading (deg), drop (agent type), sigma (x); e.g. noise=0,0.5,1,2,4")
    se.add_argument("--seeds", type=parse_seeds, default=[0], help="e.g. 0-49")
    se.add_argument("--out", type=Path, default=Path("runs/sensitivity"))
    force(se)

    sc = cmd("scenario", "simharness.scenario:scenario_command", "validate a scenario file, or list the keys")
    sc.add_argument("scenario", nargs="?", help="file to check; omit to print every key with its default")
    return p


def _version() -> str:
    from simharness import __version__

    return __version__


def run_guarded(job: Callable[[], int | None], prog: str = "simharness") -> int:
    """Run `job`; a user's mistake or a dead simulator becomes one line on stderr and an exit status."""
    try:
        return int(job() or 0)
    except UserError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    except SimulatorError as e:
        print(f"{prog}: simulator failed: {e}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; completed shards are kept, rerun to finish", file=sys.stderr)
        return 130


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_guarded(lambda: args.func(args))

if __name__ == "__main__":
    sys.exit(main())
