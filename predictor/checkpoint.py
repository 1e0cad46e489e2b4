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
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
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
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    torch.save(state, tmp)
    os.replace(tmp, path)


def read_config(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise UserError(f"{path}: missing; a checkpoint needs its config.json beside the weights")
    try:
        cfg = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise UserError(f"{path}: not valid JSON ({e})") from None
    for key in ("model", "model_config", "window"):
        if key not in (cfg if isinstance(cfg, dict) else {}):
            raise UserError(f"{path}: key {key!r} missing; expected a predictor config written by `simharness train`")
    return cfg


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
