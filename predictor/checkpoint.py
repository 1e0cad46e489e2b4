"""Checkpoints: weights (`model.pt`, a state_dict read with weights_only=True) + `config.json`.

config.json holds the model name and config, the window config, and the provenance of the run
(seed, data set content hash, split, versions). Any failure to read or fit gives one UserError line.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
from typing import Any

from simharness.errors import UserError


def versions() -> dict[str, str]:
    import importlib.metadata

    import numpy
    import torch

    out = {"python": platform.python_version(), "numpy": numpy.__version__, "torch": torch.__version__}
    try:
        out["simharness"] = importlib.metadata.version("simharness")
    except importlib.metadata.PackageNotFoundError:
        out["simharness"] = "not installed"
    return out


def atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".tmp-{path.name}.{os.getpid()}.w")  # a killed run's: removed by the next (folders)
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def non_finite_tensor(state: dict[str, Any]) -> str | None:
    """Name of the first floating-point tensor of a state_dict holding NaN or infinity, or None."""
    import torch

    for name, value in state.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(torch.isfinite(value).all()):
            return name
    return None


def save_checkpoint(model: Any, path: Path) -> None:
    """state_dict -> path, atomically; UserError (nothing written) if a weight is NaN or infinite."""
    import torch

    state = model.state_dict()
    bad = non_finite_tensor(state)
    if bad is not None:
        raise UserError(f"{path}: refusing to save weights with NaN or infinity (in {bad!r}); training diverged: "
                        "lower --lr")
    tmp = path.with_name(f".tmp-{path.name}.{os.getpid()}.w")  # a killed run's: removed by the next (folders)
    torch.save(state, tmp)
    os.replace(tmp, path)


MAX_CONFIG_BYTES = 16 << 20  # a run's config.json is a few kB (the split lists scene ids)
MAX_WIDTH = 4096  # layer widths: an LSTM of 4096 units is 0.5 GB of weights; more is not a config of ours
MAX_WINDOW_FRAMES = 1000  # history or future steps of one window
# Bounds of integer fields by name (inclusive); other integers: 0..MAX_WIDTH.
INT_BOUNDS: dict[str, tuple[int, int]] = {
    "history": (2, MAX_WINDOW_FRAMES), "future": (1, MAX_WINDOW_FRAMES), "cv_lags": (1, MAX_WINDOW_FRAMES),
    "max_neighbours": (0, 256), "max_horizon": (0, 256), "variety_k": (1, 1000), "eval_samples": (1, 1000),
    "eval_seed": (0, 2**31 - 1), "downsample": (1, 1000), "stride": (1, 100_000),
}
GRID_MAX = 256  # cells along one side of an interaction map
# Bounds of float fields by name: (low, high, low excluded); other floats: [-1e6, 1e6].
FLOAT_BOUNDS: dict[str, tuple[float, float, bool]] = {
    "history_s": (0.0, 600.0, True), "future_s": (0.0, 600.0, True), "hz": (0.0, 1000.0, True),
    "heading_window_s": (0.0, 600.0, False), "min_motion": (0.0, 1e4, False), "length_scale": (0.0, 1e6, True),
    "pos_scale": (0.0, 1e6, True),
}


def _check_fields(cls: type, values: Any, path: Path, section: str) -> None:
    """UserError naming `section.field` unless `values` holds fields of dataclass `cls` of the right types within
    bounds (checked before a model or window of those sizes is built)."""
    import dataclasses
    import math
    import typing

    if not isinstance(values, dict):
        raise UserError(f"{path}: field {section!r}: expected an object of settings, got {type(values).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    for key, v in values.items():
        if key not in fields:
            raise UserError(f"{path}: field '{section}.{key}': unknown; expected some of {', '.join(sorted(fields))}")
        hint = hints[key]
        args = typing.get_args(hint)
        optional = type(None) in args
        if optional and v is None:
            continue
        base = next((a for a in args if a is not type(None)), hint) if optional else hint
        where = f"{path}: field '{section}.{key}'"

        def number(x: Any, kind: type, lo: float, hi: float, lo_open: bool = False, where: str = where) -> None:
            ok = isinstance(x, (int, float)) and not isinstance(x, bool) and (kind is float or isinstance(x, int))
            if not ok or not math.isfinite(x) or not lo <= x <= hi or (lo_open and x == lo):
                what = "a whole number" if kind is int else "a finite number"
                span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
                raise UserError(f"{where}: expected {what} in {span}, got {x!r}"[:300])

        if base is bool:
            if not isinstance(v, bool):
                raise UserError(f"{where}: expected true or false, got {v!r}"[:300])
        elif base is int:
            number(v, int, *INT_BOUNDS.get(key, (0, MAX_WIDTH)))
        elif base is float:
            number(v, float, *FLOAT_BOUNDS.get(key, (-1e6, 1e6, False)))
        elif typing.get_origin(base) is tuple:
            kinds = typing.get_args(base)
            if not isinstance(v, (list, tuple)) or len(v) != len(kinds):
                raise UserError(f"{where}: expected a list of {len(kinds)} numbers, got {v!r}"[:300])
            for x, kind in zip(v, kinds, strict=True):
                number(x, kind, 1, GRID_MAX) if kind is int else number(x, float, 0.0, 1e4, True)
        elif base is str:
            if not isinstance(v, str):
                raise UserError(f"{where}: expected a string, got {v!r}"[:300])


def check_config(cfg: Any, path: Path) -> dict[str, Any]:
    """`cfg` (a run's config.json) if its model, model_config and window fields have the types and bounds this
    version reads, else one UserError naming the file and field."""
    from predictor.features import WindowConfig
    from predictor.models import MODELS, config_class

    if not isinstance(cfg, dict):
        raise UserError(f"{path}: expected a JSON object (a predictor config written by `simharness train`)")
    for key in ("model", "model_config", "window"):
        if key not in cfg:
            raise UserError(f"{path}: key {key!r} missing; expected a predictor config written by `simharness train`")
    if not isinstance(cfg["model"], str) or cfg["model"] not in MODELS:
        raise UserError(f"{path}: field 'model': expected one of {', '.join(MODELS)}, got {cfg['model']!r}"[:300])
    _check_fields(config_class(cfg["model"]), cfg["model_config"], path, "model_config")
    _check_fields(WindowConfig, cfg["window"], path, "window")
    window = WindowConfig.from_dict(cfg["window"])
    for key in ("history_s", "future_s"):  # steps of one window at its rate (downsample: bounded by the model's)
        if window.downsample is None and getattr(window, key) * window.hz > MAX_WINDOW_FRAMES:
            raise UserError(f"{path}: field 'window.{key}': {getattr(window, key):g} s at {window.hz:g} Hz is more "
                            f"than {MAX_WINDOW_FRAMES} steps")
    return cfg


def read_config(path: Path) -> dict[str, Any]:
    """A run's config.json, checked (`check_config`); UserError (one line) if missing, too big or invalid."""
    if not path.is_file():
        raise UserError(f"{path}: missing; a checkpoint needs its config.json beside the weights")
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise UserError(f"{path}: {path.stat().st_size:,} bytes; a run's config.json is at most {MAX_CONFIG_BYTES:,}")
    try:
        cfg = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise UserError(f"{path}: not valid JSON ({str(e).splitlines()[0][:120]})") from None
    return check_config(cfg, path)


def load_checkpoint(weights: Path, config: Path) -> tuple[Any, dict[str, Any]]:
    """(model in eval mode, config dict) from weights + config.json; UserError on any mismatch."""
    import torch

    from predictor.models import build_model

    cfg = read_config(config)
    model = build_model(cfg["model"], cfg["model_config"])
    if not weights.is_file():
        raise UserError(f"{weights}: missing checkpoint file")
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for damaged files; all mean the same to the user
        raise UserError(f"{weights}: corrupt or not a torch checkpoint ({type(e).__name__}: "
                        f"{str(e).splitlines()[0][:120] if str(e) else ''})") from None
    if not isinstance(state, dict):
        raise UserError(f"{weights}: holds a {type(state).__name__}, expected a state_dict")
    mine = model.state_dict()
    missing = sorted(set(mine) - set(state))
    extra = sorted(set(state) - set(mine))
    shapes = sorted(k for k in set(mine) & set(state) if tuple(mine[k].shape) != tuple(state[k].shape))
    if missing or extra or shapes:
        what = "; ".join(f"{n} {', '.join(v[:3])}{'...' if len(v) > 3 else ''}" for n, v in
                         (("missing", missing), ("unexpected", extra), ("wrong shape", shapes)) if v)
        raise UserError(f"{weights}: does not fit model {cfg['model']!r} of {config.name} ({what}); "
                        "is it another model's checkpoint?")
    bad = non_finite_tensor(state)
    if bad is not None:
        raise UserError(f"{weights}: weight {bad!r} holds NaN or infinity; the checkpoint is unusable (retrain it)")
    model.load_state_dict(state)
    model.eval()
    return model, cfg
