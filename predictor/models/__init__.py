"""Model registry: a model is one file here plus one entry in MODELS.

A model class takes its config dataclass, has `name`, and `forward(batch) -> (B, F, 5)` (mu_x, mu_y,
sigma_x, sigma_y, rho) in the target's frame, where batch is `predictor.features.Batch.tensors()`.
Its config dataclass has `to_dict()` and fields `history`, `future` (frames) filled in from the windows.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

from simharness.errors import UserError

# name -> ("module:Class", "module:ConfigClass", fixed config overrides)
MODELS: dict[str, tuple[str, str, dict[str, Any]]] = {
    "traphic": ("predictor.models.traphic:TraPHic", "predictor.models.traphic:TraPHicConfig",
                {"horizon": True, "heterogeneous": True}),
    "traphic-he": ("predictor.models.traphic:TraPHic", "predictor.models.traphic:TraPHicConfig",
                   {"horizon": False, "heterogeneous": True}),
    "traphic-ho": ("predictor.models.traphic:TraPHic", "predictor.models.traphic:TraPHicConfig",
                   {"horizon": True, "heterogeneous": False}),
    "traphic-b": ("predictor.models.traphic:TraPHic", "predictor.models.traphic:TraPHicConfig",
                  {"horizon": False, "heterogeneous": False}),
    # The paper's baselines.
    "rnn-ed": ("predictor.models.rnn_ed:RNNED", "predictor.models.rnn_ed:RNNEDConfig", {}),
    "social-lstm": ("predictor.models.social_lstm:SocialLSTM", "predictor.models.social_lstm:SocialLSTMConfig", {}),
    # Social-GAN decodes step by step from its own samples: its residual form keeps the last displacement.
    "social-gan": ("predictor.models.social_gan:SocialGAN", "predictor.models.social_gan:SocialGANConfig",
                   {"cv_lags": 1}),
    "cs-lstm": ("predictor.models.cs_lstm:CSLSTM", "predictor.models.cs_lstm:CSLSTMConfig", {}),
}


def _load(target: str) -> Any:
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def config_class(name: str) -> type:
    if name not in MODELS:
        raise UserError(f"unknown model {name!r}; expected one of {', '.join(MODELS)}")
    return _load(MODELS[name][1])


def build_model(name: str, config: dict[str, Any] | None = None) -> Any:
    """A fresh model `name` with config fields from `config` (the registry's fixed overrides win)."""
    cls_cfg = config_class(name)
    fields = {f.name for f in dataclasses.fields(cls_cfg)}
    given = dict(config or {})
    unknown = set(given) - fields
    if unknown:
        raise UserError(f"model {name!r}: unknown config keys {sorted(unknown)}")
    given.update(MODELS[name][2])
    given = {k: tuple(v) if isinstance(v, list) else v for k, v in given.items()}
    cfg = cls_cfg(**given)
    if not 1 <= cfg.cv_lags < cfg.history:
        raise UserError(f"model {name!r}: cv_lags {cfg.cv_lags} must be from 1 to history - 1 ({cfg.history - 1})")
    model = _load(MODELS[name][0])(cfg)
    if cfg.residual and cfg.cv_lags > 1:
        from predictor.models.gaussian import LagBlend

        model = LagBlend(model)
    model.name = name
    return model
