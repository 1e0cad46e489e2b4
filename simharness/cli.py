"""The `simharness` command line: one subcommand per job, each calling one function elsewhere.

Bad input (`UserError`) prints one line `simharness: error: ...` and exits 2.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
import textwrap
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


def seed_value(text: str) -> int:
    """A single seed option: a whole number in 0..2^31-1 (torch and the simulators take no other)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected a seed in 0..{MAX_SEED}, got {text}")
    return value


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


DESCRIPTION = (
    "A closed-loop evaluation harness for trajectory predictors in dense, heterogeneous traffic: simulate SUMO and "
    "highway-env scenarios into data sets, train and score predictors on them open-loop, and drive an ego on a "
    "predictor's forecasts to score what prediction errors cost.")

EPILOG = """\
a first run:
  simharness generate sumo_arterial_dense --seeds 0-9 --out data/dense
  simharness evaluate --data data/dense --model traphic --split all
  simharness closedloop stress/cut_in --predictor traphic --seeds 0-9

`simharness COMMAND --help` lists a command's options with their defaults."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, "(required)", or nothing for a flag; descriptions keep their
    line breaks (each line wrapped to the terminal) and indented lines (examples) as written."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, max_help_position=28)

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)  # keep --no-residual whole

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n".join(indent + line if line[:1].isspace() or not line else
                         textwrap.fill(line, width, initial_indent=indent, subsequent_indent=indent,
                                       break_on_hyphens=False)
                         for line in text.splitlines())

    def add_argument(self, action: argparse.Action) -> None:
        if action.nargs == argparse.PARSER:  # argparse measures the command names without their indent
            longest = max(map(len, action.choices or {"": None}))
            self._action_max_length = max(self._action_max_length, longest + self._current_indent + 2)
        super().add_argument(action)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if action.required and action.option_strings:
            return f"{text} (required)"
        if "default" in text or not action.option_strings:  # positionals: given, or their help says what if not
            return text
        if action.default is None:
            return f"{text} (default: none)"
        if isinstance(action, argparse.BooleanOptionalAction):  # the flag that is in force when neither is given
            return f"{text} (default: {action.option_strings[0 if action.default else 1]})"
        if action.nargs == 0:  # store_true and the like: off unless given
            return text
        return super()._get_help_string(action)


def _call(target: str) -> Callable[[argparse.Namespace], int | None]:
    """Lazy 'module:function' so that `simharness --help` does not import torch or SUMO."""
    module, func = target.split(":")

    def run(args: argparse.Namespace) -> int | None:
        return getattr(importlib.import_module(module), func)(args)

    return run


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="simharness", description=DESCRIPTION, epilog=EPILOG,
                                formatter_class=HelpFormatter)
    p.add_argument("--version", action="version", version=f"simharness {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", title="commands")

    def cmd(name: str, target: str, help: str, parents: Sequence[argparse.ArgumentParser] = (),
            **kw: str) -> argparse.ArgumentParser:
        """A subcommand whose description is its one-line `help` (or a longer `description`)."""
        kw.setdefault("description", help[0].upper() + help[1:] + ".")
        sp = sub.add_parser(name, help=help, parents=list(parents), formatter_class=HelpFormatter, **kw)
        sp.set_defaults(func=_call(target))
        return sp

    executor_args = argparse.ArgumentParser(add_help=False)
    run_group = executor_args.add_argument_group("parallel runs")
    run_group.add_argument("--workers", type=int, default=2, metavar="N", help="parallel processes")
    run_group.add_argument("--executor", choices=["local", "ray"], default="local",
                           help="local: a process pool on this machine; ray: a Ray cluster")
    run_group.add_argument("--address", default=None,
                           help="Ray cluster address, with --executor ray (default: start a local Ray)")

    force_help = "write into a non-empty --out folder (replacing files of the same name)"

    def force(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--force", action="store_true", help=force_help)

    g = cmd("generate", "simharness.generation:generate_command", "simulate a scenario over seeds into a data set",
            parents=[executor_args], description="Simulate a scenario once per seed into a Parquet data set, one "
            "shard per seed.\nA rerun into the same folder makes only the shards that are missing or damaged.")
    g.add_argument("scenario", help="scenario file, or a shipped scenario's name (`simharness scenario` lists keys)")
    g.add_argument("--seeds", type=parse_seeds, default="0", metavar="SEEDS", help="e.g. 0-99 or 1,5,9")
    g.add_argument("--out", type=Path, required=True, metavar="DIR", help="data set folder")
    g.add_argument("--duration", type=finite_float, default=None, metavar="S",
                   help="recorded seconds per scene (default: the scenario's)")

    s = cmd("stats", "simharness.stats:stats_command", "a data set's figures (the TraPHic paper's Table 1)",
            description="Print a data set's figures as the TraPHic paper's Table 1 gives them (agents per frame, "
                        "density, the mix of agent types), speeds and lateral spread by type, and collisions.")
    s.add_argument("data", type=Path, help="data set folder")
    s.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    s.add_argument("--figure", type=Path, default=None, metavar="PNG", help="write a top-down frame figure there")

    t = cmd("train", "predictor.train:train_command", "train a predictor on a data set",
            usage="simharness train --data DIR --out RUN [--model NAME] [--epochs N]\n"
                  "                        [--device auto|cpu|cuda] [--init RUN|shipped] [--force]\n"
                  "                        [research settings]",
            description="Train a predictor on a data set's training scenes and keep the epoch that does best on "
                        "its validation scenes; `simharness evaluate --model RUN` scores the test scenes it held out. "
                        "The research settings' defaults are the tuned ones (docs/training.md).")
    t.add_argument("--data", type=Path, required=True, metavar="DIR", help="data set folder")
    t.add_argument("--model", default="traphic", metavar="NAME",
                   help="traphic; its ablations traphic-b, traphic-he, traphic-ho; or a baseline: cs-lstm, "
                        "social-lstm, social-gan, rnn-ed")
    t.add_argument("--out", type=Path, required=True, metavar="RUN", help="run folder to write")
    t.add_argument("--epochs", type=int, default=16, metavar="N", help="maximum passes over the data")
    t.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="auto: a CUDA GPU if torch sees one")
    t.add_argument("--init", default=None, metavar="RUN|shipped",
                   help="fine-tune: start from a run's weights or the shipped ones (default: random)")
    force(t)

    r = t.add_argument_group("research settings (split and windows)")
    r.add_argument("--test-scenes", type=parse_names, default=None, metavar="NAMES",
                   help="hold these scenes out for test, e.g. hotel or TRAF11,TRAF12 (default: a split by a hash of "
                        "the scene ids, or the data set's own *_train / *_val files)")
    r.add_argument("--seed", type=seed_value, default=0, metavar="N",
                   help="for initial weights, batch order and augmentation")
    r.add_argument("--protocol", default=None, metavar="NAME",
                   help="windows of this evaluation protocol: eth-ucy, apolloscape (default: 3 s + 5 s at 5 Hz, "
                        "the traphic protocol)")
    r.add_argument("--max-samples", type=int, default=None, metavar="N",
                   help="train on a random N of the windows (default: all)")
    r = t.add_argument_group("research settings (optimisation and checkpoint choice)")
    r.add_argument("--lr", type=finite_float, default=1e-3, help="Adam's learning rate")
    r.add_argument("--batch-size", type=int, default=128, metavar="N", help="windows per step")
    r.add_argument("--warmup-epochs", type=int, default=2, metavar="N",
                   help="epochs of mean error only, before sigma and rho follow the Gaussian NLL")
    r.add_argument("--lr-schedule", choices=["cosine", "plateau", "constant"], default="cosine",
                   help="cosine: linear warm-up, then cosine decay; plateau: halve when validation stalls")
    r.add_argument("--select", choices=["ade", "mse", "loss"], default="ade",
                   help="the validation measure that picks the checkpoint and drives early stopping")
    r.add_argument("--patience", type=int, default=3, metavar="N",
                   help="stop after N epochs past the warm-up without a better validation measure")
    r = t.add_argument_group("research settings (the model's form and loss)")
    r.add_argument("--residual", action=argparse.BooleanOptionalAction, default=True,
                   help="predict a correction to constant-velocity extrapolation, or the means directly (the paper)")
    r.add_argument("--cv-lags", type=cv_lags, default="auto", metavar="auto|N",
                   help="residual form: blend the velocities over up to N steps (for jittery tracks)")
    r.add_argument("--cv-gate", action=argparse.BooleanOptionalAction, default=True,
                   help="residual form: learn that blend per track from its jitter, or one blend for all")
    r.add_argument("--cv-gate-pool", action=argparse.BooleanOptionalAction, default=True,
                   help="with --cv-gate: read the jitter pooled over the target and its neighbours, or its own")
    r.add_argument("--mean-loss", choices=["ade", "mse", "nll"], default="ade",
                   help="what fits the means: Euclidean error, squared error, or the NLL (the paper)")
    r.add_argument("--correction-cost", type=float, default=0.0, metavar="C",
                   help="residual form: each metre the means move from constant velocity costs C metres of error, "
                        "so a correction is kept only where it pays for itself; 0: off")
    r = t.add_argument_group("research settings (augmentation)")
    r.add_argument("--augment", action=argparse.BooleanOptionalAction, default=True,
                   help="mirror a random half of every batch left-right")
    r.add_argument("--scale-jitter", type=float, default=0.0, metavar="J",
                   help="scale each sample by a random factor in [1/(1+J), 1+J]; 0: off")
    r.add_argument("--reannotate-smooth", type=float_list, default=None, metavar="S[,S...]",
                   help="also train on copies of the scenes smoothed over S seconds; 0: none (default: 0.5 on "
                        "recorded data with --cv-gate, else none)")
    r.add_argument("--reannotate-noise", type=float_list, default=None, metavar="M[,M...]",
                   help="also train on copies with M metres of white noise; 0: none (default: 0.1 where "
                        "--reannotate-smooth defaults to 0.5, else none)")
    r.add_argument("--reannotate-drift", type=float_list, default=None, metavar="M[,M...]",
                   help="also train on copies with M metres of drift (noise correlated over 0.2-1 s, as a tracker's "
                        "filter leaves it); 0: none (default: none)")

    e = cmd("evaluate", "simharness.evaluation:evaluate_command", "score a predictor open-loop on a data set",
            description="Score a predictor open-loop on a data set's test scenes (or all): ADE / FDE as mean "
                        "Euclidean error and RMSE, RMSE per second, NLL, by agent type and local density; writes "
                        "metrics.json and two figures.")
    e.add_argument("--data", type=Path, required=True, metavar="DIR", help="data set folder")
    e.add_argument("--model", required=True, metavar="NAME",
                   help="traphic (shipped weights), a baseline, const-vel, const-vel:N (the mean velocity over the "
                        "last N history steps), a run folder, or your own: FILE.py:NAME, MODULE:NAME or an installed "
                        "plug-in (docs/predictors.md)")
    e.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="folder for metrics.json and figures (default: runs/evaluate/MODEL)")
    force(e)
    e.add_argument("--protocol", default="traphic", metavar="NAME",
                   help="traphic (3 s / 5 s at 5 Hz), eth-ucy (8 / 12 frames at 2.5 Hz) or apolloscape (3 / 3 frames "
                        "at 2 Hz)")
    e.add_argument("--split", default="test", choices=["test", "all"],
                   help="test: the scenes `simharness train` held out; all: every scene")
    e.add_argument("--test-scenes", type=parse_names, default=None, metavar="NAMES",
                   help="the scenes named by `train --test-scenes`, e.g. hotel (default: those the model's run "
                        "config records when it was trained on this data set, else the hash split's)")

    c = cmd("closedloop", "simharness.closedloop:closedloop_command", "drive an ego on a predictor's forecasts",
            parents=[executor_args],
            description="Drive an ego through a scenario on a predictor's forecasts, once per seed, and score what "
                        "happened: collisions, near misses, progress, the forecasts' online error, with 95% "
                        "bootstrap intervals.\nWrites scores.json, report.md and every episode (docs/closedloop.md).")
    c.add_argument("scenario", help="scenario file, a shipped scenario's name (e.g. stress/cut_in), or a data set "
                                    "folder to replay (docs/replay.md)")
    c.add_argument("--predictor", default="traphic", metavar="NAME[,NAME...]",
                   help="traphic, const-vel, a run folder, FILE.py:NAME, MODULE:NAME or an installed plug-in "
                        "(docs/predictors.md); or a reference: oracle (the true future), static (no motion), none "
                        "(the simulator's own driver); comma-separated for several (default: traphic)")
    c.add_argument("--planner", default="pdm", metavar="NAME",
                   help="the ego's planner: pdm (default), sampling, ppo (the shipped policy; ignores forecasts), a "
                        "stable-baselines3 policy .zip, FILE.py:NAME, MODULE:NAME or an installed plug-in")
    c.add_argument("--seeds", type=parse_seeds, default="0", metavar="SEEDS", help="e.g. 0-19 or 1,5,9")
    c.add_argument("--out", type=Path, default=Path("runs/closedloop"), metavar="DIR", help="results folder")
    force(c)
    c.add_argument("--animate", type=int, default=0, metavar="N", help="write an animation of the first N episodes")
    c.add_argument("--reaction", default=None, choices=["reactive", "cut_in", "ignore", "log"],
                   help="how background agents treat the ego (default: the scenario's); a replayed data set: log "
                        "(the recording as it was) or reactive (its agents keep a gap to the ego)")

    b = cmd("benchmark", "simharness.benchmark:benchmark_command", "train and compare every method (paper tables)",
            parents=[executor_args],
            description="Train TraPHic, its ablations and the paper's baselines on one split of a data set and "
                        "score each on its test scenes beside constant velocity: the paper's tables as Markdown, "
                        "JSON and a figure.")
    b.add_argument("--data", type=Path, required=True, metavar="DIR", help="data set folder")
    b.add_argument("--profile", choices=["quick", "medium", "full"], default="quick",
                   help="training budget: quick (a smoke test), medium (about 10-15 CPU-minutes), full (16 epochs, "
                        "at most 80,000 windows: within 3 hours on 2 cores)")
    b.add_argument("--out", type=Path, default=Path("runs/benchmark"), metavar="DIR", help="results folder")
    force(b)
    b.add_argument("--residual", action=argparse.BooleanOptionalAction, default=True,
                   help="train every method as a correction to constant velocity, or as in the paper")
    b.add_argument("--protocol", default="traphic", metavar="NAME",
                   help="evaluation protocol, and training windows of its length and rate: traphic, eth-ucy, "
                        "apolloscape")

    i = cmd("import", "simharness.io.importers:import_command", "convert a public data set into ours",
            description="Convert a public data set's files into a simharness data set (Parquet, one shard per "
                        "scene).\nPositions stay in the source's units (TRAF: pixels), and the data set says so.")
    i.add_argument("format", help="eth-ucy, traf, apolloscape, commonroad, argoverse2, tracknpred")
    i.add_argument("src", type=Path, nargs="+", help="source file(s) or folder")
    i.add_argument("--out", type=Path, required=True, metavar="DIR", help="data set folder to write")
    i.add_argument("--allow-pickle", action="store_true", help="allow reading pickled .npy files you trust")
    i.add_argument("--type-default", default=None, metavar="TYPE",
                   help="traf: the agent type of ids that are bare numbers (no class in the file), e.g. car "
                        "(default: other)")
    i.add_argument("--pixel-scale", type=float, default=None, metavar="M_PER_PX",
                   help="traf: metres per pixel for videos without cars to estimate it from, e.g. 0.03 "
                        "(default: estimated from the cars)")
    i.add_argument("--fps", type=float, default=None, help="traf: video frame rate (default: 20, the data set's)")
    i.add_argument("--image-size", default=None, metavar="WxH",
                   help="traf: video frame size in pixels (default: from the boxes' extent)")

    x = cmd("export", "simharness.io.exporters:export_command", "write a data set in another tool's layout",
            description="Write a data set in another tool's layout: tracknpred, the layout of the TraPHic "
                        "authors' TrackNPred / CS-LSTM code, so that their code trains on it.")
    x.add_argument("format", help="tracknpred")
    x.add_argument("data", type=Path, help="data set folder")
    x.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder to write")

    w = cmd("sweep", "simharness.sweep:sweep_command", "closed loop over a grid of scenario settings",
            parents=[executor_args],
            description="Run the closed loop over a grid of scenario settings (e.g. traffic demand), the same "
                        "seeds in every cell: one table and one figure of the scores against the settings.")
    w.add_argument("scenario", help="scenario file, or a shipped scenario's name")
    w.add_argument("--set", dest="sets", type=parse_set, action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a scenario key and its values, e.g. demand_scale=0.5,1,2; repeat for a grid "
                        "(default: the scenario as it is)")
    w.add_argument("--predictor", default="traphic", help="the forecasts the ego drives on, as in closedloop")
    w.add_argument("--seeds", type=parse_seeds, default="0", metavar="SEEDS", help="e.g. 0-9 or 1,5,9")
    w.add_argument("--out", type=Path, default=Path("runs/sweep"), metavar="DIR", help="results folder")
    force(w)

    se = cmd("sensitivity", "simharness.closedloop.sensitivity:sensitivity_command",
             "closed loop over a grid of forecast perturbations (what prediction error costs)",
             parents=[executor_args],
             description="Run the closed loop with the predictor's forecasts perturbed over a grid (noise, "
                         "latency, speed, heading, a dropped agent type, sigma), the same seeds in every cell: "
                         "collisions, near misses, progress and the composite score against the measured online "
                         "error.")
    se.add_argument("scenario", help="scenario file, a shipped scenario's name (e.g. stress/step_out), or a data set "
                                     "folder to replay")
    se.add_argument("--predictor", default="oracle", metavar="NAME",
                    help="oracle (default), static, const-vel, traphic, a run folder, FILE.py:NAME, MODULE:NAME or "
                         "an installed plug-in (docs/predictors.md)")
    se.add_argument("--perturb", action="append", default=[], metavar="KEY=V1,V2,...",
                    help="noise (m), latency (frames), speed (x), heading (deg), drop (agent type) or sigma (x), "
                         "e.g. noise=0,0.5,1,2,4; repeat for a grid (default: none, the forecasts as they are)")
    se.add_argument("--seeds", type=parse_seeds, default="0", metavar="SEEDS", help="e.g. 0-49 or 1,5,9")
    se.add_argument("--out", type=Path, default=Path("runs/sensitivity"), metavar="DIR", help="results folder")
    force(se)

    st = cmd("stress", "simharness.closedloop.suite:stress_command",
             "every stress scenario with every ego on the same seeds: leaderboard with paired verdicts",
             parents=[executor_args])
    st.add_argument("--predictor", default="oracle,traphic,const-vel,static,none",
                    help="egos, comma-separated: registered predictors, run folders, oracle, static, none")
    st.add_argument("--planner", default=None,
                    help="planner egos beside them, comma-separated: ppo (the shipped policy), a policy .zip, "
                         "file.py:NAME, module:NAME; each drives on constant-velocity forecasts (default: none)")
    st.add_argument("--seeds", type=parse_seeds, default=None,
                    help="e.g. 0-49 (default: 0-49; with --until-resolved the seeds batches are drawn from, 0-999)")
    st.add_argument("--until-resolved", action="store_true",
                    help="add batches of --batch seeds until the --resolve ego's pooled at-fault difference from "
                         "--baseline has a 95%% CI half-width <= --target, or --budget-minutes are spent")
    st.add_argument("--budget-minutes", type=finite_float, default=30.0, help="wall-clock budget with --until-resolved")
    st.add_argument("--target", type=finite_float, default=0.03, help="CI half-width that counts as resolved")
    st.add_argument("--batch", type=int, default=20, help="seeds per batch with --until-resolved")
    st.add_argument("--baseline", default="const-vel", help="the ego every other is paired against")
    st.add_argument("--resolve", default=None,
                    help="the ego resolved against --baseline with --until-resolved (default: traphic if run, else "
                         "the first prediction-driven ego)")
    st.add_argument("--scenarios", default=None,
                    help="stress scenario names or scenario files, comma-separated (default: all of "
                         "scenarios/stress/)")
    st.add_argument("--duration", type=finite_float, default=None,
                    help="override every scenario's duration, s (default: each scenario's own)")
    st.add_argument("--out", type=Path, default=Path("runs/stress"), help="leaderboard.md, .json and .png go here")
    force(st)

    sc = cmd("scenario", "simharness.scenario:scenario_command", "validate a scenario file, or list the keys",
             description="Check a scenario file, or with no file print every key with its default and meaning.")
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
    except OSError as e:
        if e.filename is None:  # not about a path the user named: a bug, keep its traceback
            raise
        # a path that cannot be written or read (read-only folder, under a regular file, disk full)
        print(f"{prog}: error: {e.filename}: {e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; completed shards are kept, rerun to finish", file=sys.stderr)
        return 130


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_guarded(lambda: args.func(args))

if __name__ == "__main__":
    sys.exit(main())
