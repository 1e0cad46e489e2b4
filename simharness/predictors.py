"""The built-in predictors: names that ship with the package, and run folders of `simharness train`.

`builtin_predictor("const-vel" | "const-vel:N" | "traphic" | "traphic-b" | ... | RUN_FOLDER)` returns a
`Predictor` (None for other names). Everything else (a user's `file.py:NAME`, `module:NAME`, installed
entry points) is resolved by `simharness.plugins.load_predictor`, the loader every command calls.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from simharness.errors import UserError
from simharness.scene import Predictor


def _const_vel(lag: int = 1) -> Predictor:
    from predictor.models.const_vel import ConstantVelocity

    return ConstantVelocity(lag)


def _const_vel_lag(key: str) -> Predictor | None:
    """`const-vel:N`: constant velocity from the mean displacement over the last N history steps (a smoothed
    reference for jittery tracks: on TRAF's boxes N = 5 beats the last step by a fifth); None for other names."""
    head, sep, tail = key.partition(":")
    if head != "const-vel" or not sep:
        return None
    if not tail.isdigit() or int(tail) < 1:
        raise UserError(f"predictor {key!r}: expected const-vel:N with N a whole number of history steps >= 1")
    return _const_vel(int(tail))


def _shipped(name: str) -> Callable[[], Predictor]:
    def load() -> Predictor:
        from predictor.predict import ModelPredictor

        return ModelPredictor.shipped(name)

    return load


PREDICTORS: dict[str, Callable[[], Predictor]] = {
    "const-vel": _const_vel,
    "traphic": _shipped("traphic"),
    "rnn-ed": _shipped("rnn-ed"),  # the paper's baselines: weights from `simharness benchmark` (predictor/weights)
    "social-lstm": _shipped("social-lstm"),
    "social-gan": _shipped("social-gan"),
    "cs-lstm": _shipped("cs-lstm"),
}


def available() -> list[str]:
    """Registered names (shipped ablation weights are added when their files exist)."""
    from predictor.predict import WEIGHTS

    extra = [p.stem for p in sorted(WEIGHTS.glob("traphic-*.pt")) if p.with_suffix(".json").is_file()]
    return [*PREDICTORS, *[e for e in extra if e not in PREDICTORS]]


def builtin_predictor(name_or_run: str | Path) -> Predictor | None:
    """A predictor by registered name, shipped weights name, or run folder from `simharness train`; None for any
    other name (a plug-in, or unknown)."""
    key = str(name_or_run)
    if key in PREDICTORS:
        return PREDICTORS[key]()
    if (smoothed := _const_vel_lag(key)) is not None:
        return smoothed
    if key in available():
        return _shipped(key)()
    path = Path(key)
    if path.is_dir():
        from predictor.predict import ModelPredictor

        return ModelPredictor.from_run(path)
    return None


def load_predictor(name_or_run: str | Path) -> Predictor:
    """Any predictor name: built-in, run folder or plug-in (`simharness.plugins.load_predictor`)."""
    from simharness.plugins import load_predictor as load

    return load(name_or_run)


def split_scenes(scene_ids: list[str], test_scenes: list[str] | None = None) -> dict[str, list[str]]:
    """The train/val/test split by scene that training used (re-exported for evaluation); test_scenes: the
    scenes held out by name (leave-one-scene-out), as given to `simharness train --test-scenes`."""
    from predictor.split import split_scenes as split

    return split(scene_ids, test_scenes=test_scenes)
