"""Training loop: Adam, MSE warm-up then bivariate Gaussian NLL, validation every epoch, best checkpoint.

The learning rate follows a schedule (`lr_schedule`: cosine decay after a linear warm-up, by default; halving
on a validation plateau; or constant), and training stops early when the validation criterion has not
improved for `patience` epochs of the NLL phase; model.pt always holds the best epoch's weights.
A run folder holds model.pt (best validation state_dict), config.json (model and window config, seed,
data set hash, split, versions, best epoch) and log.csv (losses per epoch). Splits are by scene
(predictor.split), the same that evaluation uses for its test split.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from predictor.checkpoint import atomic_write_text, read_config, save_checkpoint, versions
from predictor.features import FeatureStore, WindowConfig
from predictor.reannotate import VERSION as REANNOTATE_VERSION
from predictor.reannotate import Level, copy_id, level_name, parse_levels, reannotated, simulated
from predictor.split import describe_split, split_scenes
from simharness.errors import UserError
from simharness.scene import Scene

VAL_SAMPLES = 4000  # validation windows scored each epoch by the CLI (a fixed, seeded subset)
LR_SCHEDULES = ("cosine", "plateau", "constant")
SELECT = ("loss", "mse", "ade")  # the validation criterion that picks the checkpoint (`train`)
AUTO_LAGS = 5  # the longest lag `cv_lags = auto` considers (1 s at 5 Hz)
LR_FLOOR = 0.05  # cosine decays to this fraction of the learning rate
LR_WARMUP = 0.05  # fraction of the steps (at most one epoch) over which the cosine schedule ramps up


def resolve_device(device: str) -> Any:
    """"auto" (CUDA if torch sees a GPU, else the CPU), "cpu" or "cuda" -> torch.device; UserError otherwise."""
    import torch

    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device not in ("cpu", "cuda"):
        raise UserError(f"unknown device {device!r}; expected auto, cpu or cuda")
    if device == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda: torch sees no CUDA GPU here (a CPU-only torch, or no driver); use auto or cpu")
    return torch.device(device)


def lr_factor(step: int, total: int, warmup: int) -> float:
    """The cosine schedule's multiplier of the learning rate at optimiser step `step` of `total`: linear from
    1/warmup to 1 over `warmup` steps, then a cosine from 1 down to LR_FLOOR at the last step."""
    if step < warmup:
        return (step + 1) / warmup
    frac = min(1.0, (step - warmup) / max(1, total - warmup))
    return LR_FLOOR + (1 - LR_FLOOR) * 0.5 * (1 + math.cos(math.pi * frac))


def open_data(data: Path) -> tuple[str, list[str], Any]:
    """(content hash, scene ids, scenes_fn) of a data set folder; scenes are read only if the cache misses."""
    # The one harness module predictor/ reads: the data set format, in the direction data flows.
    from simharness.io.parquet import Dataset

    ds = Dataset(Path(data))  # checks every shard's size and sha256 against the manifest
    key = ds.content_hash  # of the shards as found: a cache never outlives the content it was built from

    def scenes_fn() -> tuple[list[Scene], list[str]]:
        scenes = [ds.scene(i) for i in range(len(ds))]
        return [s.replace(meta={**s.meta, "scene_id": sid}) for s, sid in zip(scenes, ds.scene_ids, strict=True)], \
            list(ds.scene_ids)

    return key, list(ds.scene_ids), scenes_fn


def load_windows(data: Path, window: WindowConfig, progress: bool = True,
                 cache_dir: Path | None = None) -> FeatureStore:
    """The cached FeatureStore of a data set (built on first use; cache in `cache_dir`, by default
    `predictor.windows_cache.default_cache_dir()`, outside the data set folder)."""
    key, _, scenes_fn = open_data(data)
    return _cached_windows(key, scenes_fn, window, progress, cache_dir)


def _cached_windows(key: str, scenes_fn: Any, window: WindowConfig, progress: bool,
                    cache_dir: Path | None) -> FeatureStore:
    """The FeatureStore of an opened data set (`open_data`), from the cache keyed on its content hash."""
    from predictor.windows_cache import cached_store, default_cache_dir

    return cached_store(Path(cache_dir) if cache_dir else default_cache_dir(), str(key), window, scenes_fn,
                        progress=progress)


def _with_copies(key: str, scenes_fn: Any, train: Sequence[str], levels: Sequence[Level], window: WindowConfig
                 ) -> tuple[str, Any]:
    """(cache key, scenes_fn) of a data set with its training scenes copied at each re-annotation level."""
    train = sorted(train)
    tag = hashlib.sha256(json.dumps([REANNOTATE_VERSION, train, [level_name(lv) for lv in levels]]).encode()
                         ).hexdigest()[:16]

    def with_copies() -> tuple[list[Scene], list[str]]:
        scenes, ids = scenes_fn()
        extra = [(reannotated(s, sid, lv, window.scale_for(s)), copy_id(sid, lv))
                 for s, sid in zip(scenes, ids, strict=True) if sid in train for lv in levels]
        return ([*scenes, *(c.replace(meta={**c.meta, "scene_id": cid}) for c, cid in extra)],
                [*ids, *(cid for _, cid in extra)])

    return f"{key}-reannotated-{tag}", with_copies


def _copy_table(store: FeatureStore, train: Sequence[str], levels: Sequence[Level]) -> np.ndarray:
    """(samples, levels) int64: each training sample's index in each copy of its scene (-1 elsewhere). A copy has
    the same windows as its original in the same order (noise and smoothing move positions, not presence), and a
    store keeps each scene's samples together, in scene order."""
    if not levels:
        return np.zeros((0, 0), np.int64)
    table = np.full((len(store), len(levels)), -1, np.int64)
    scene = store.a["sample_scene"]
    bounds = np.searchsorted(scene, np.arange(len(store.scene_ids) + 1))  # scene i: samples bounds[i]:bounds[i + 1]
    where = {sid: i for i, sid in enumerate(store.scene_ids)}
    for sid in train:
        a, b = bounds[where[sid]], bounds[where[sid] + 1]
        for k, lv in enumerate(levels):
            c, d = bounds[where[copy_id(sid, lv)]], bounds[where[copy_id(sid, lv)] + 1]
            if d - c != b - a:
                raise UserError(f"re-annotated copy {copy_id(sid, lv)!r} has {d - c} windows, its scene {b - a}; "
                                "clear the windows cache (~/.cache/simharness/windows)")
            table[a:b, k] = np.arange(c, d)
    return table


def _to(batch: dict[str, Any], device: Any) -> dict[str, Any]:
    """A batch's tensors on `device` (as they are on the CPU)."""
    return batch if device.type == "cpu" else {k: v.to(device, non_blocking=True) for k, v in batch.items()}


def _epoch_eval(model: Any, store: FeatureStore, idx: np.ndarray, batch_size: int, device: Any) -> dict[str, float]:
    import torch

    from predictor.losses import ade, gaussian_nll, mse

    tot = {"mse": 0.0, "nll": 0.0, "ade": 0.0}
    n = 0
    model.eval()
    with torch.inference_mode():
        for i in range(0, len(idx), batch_size * 4):
            b = _to(store.batch(idx[i:i + batch_size * 4]).tensors(), device)
            out = model(b)
            w = float(b["fut_valid"].sum())
            tot["mse"] += float(mse(out, b["fut"], b["fut_valid"])) * w
            tot["nll"] += float(gaussian_nll(out, b["fut"], b["fut_valid"])) * w
            tot["ade"] += float(ade(out, b["fut"], b["fut_valid"])) * w
            n += w
    model.train()
    return {k: v / max(n, 1) for k, v in tot.items()}


def train(data: Path, model: str = "traphic", out: Path = Path("runs/train"), epochs: int = 16,
          warmup_epochs: int = 2, batch_size: int = 128, lr: float = 1e-3, seed: int = 0,
          max_samples: int | None = None, window: WindowConfig | None = None,
          model_config: dict[str, Any] | None = None, threads: int | None = None,
          progress: bool = True, max_val_samples: int | None = None,
          test_scenes: list[str] | None = None, cache_dir: Path | None = None, lr_schedule: str = "cosine",
          patience: int | None = None, device: str = "cpu", mean_loss: str = "nll",
          init: str | Path | None = None, select: str = "loss", augment: bool = False,
          scale_jitter: float = 0.0, reannotate: Sequence[Level] = (), correction_cost: float = 0.0
          ) -> dict[str, Any]:
    """Train `model` on the train split of `data`, keep the best on the val split -> summary dict.

    lr_schedule: "cosine" (linear warm-up over LR_WARMUP of the steps, then cosine decay to LR_FLOOR x lr),
    "plateau" (halve when an epoch does not improve validation) or "constant". patience: stop after this many
    epochs of the NLL phase without a better validation criterion (None: run every epoch). device: "cpu",
    "cuda" or "auto". mean_loss: after the warm-up, "nll" trains the means by the joint NLL (the paper), "mse" by
    MSE while sigma and rho follow the NLL around them (losses.nll_mse), "ade" likewise by the mean Euclidean error
    (losses.nll_ade; the warm-up too: robust to the huge misses of real tracks). init: start from these weights instead
    of random ones (fine-tuning, e.g. sim-to-real): a run folder, or "shipped" for predictor/weights/<model>; its
    model and model config must be this run's (`init_weights`). select: the validation criterion that picks the
    checkpoint: "loss" (the epoch's own loss: MSE in the warm-up, then NLL), or "mse" / "ade" (the means' squared or
    Euclidean error over the epochs whose sigma is fitted: those after the warm-up, and the starting weights when
    they come from a trained run (`init`); a warm-up checkpoint's untrained sigma made planners collide; every
    epoch for a model without sigma, Social-GAN).
    augment: mirror a random half of every batch (predictor.augment). scale_jitter: scale every training sample by
    a log-uniform factor in [1 / (1 + j), 1 + j] (0: off; predictor.augment.scale_batch). reannotate: levels
    (`predictor.reannotate`) at which every training scene is copied; each training sample is then drawn from the
    original or one of its copies, uniformly, anew every epoch (validation stays on the original scenes).
    correction_cost: residual form: add this times the mean distance of the means from constant velocity
    (losses.correction) to the loss, so a correction is kept only where it pays for itself (0: off).
    Writes out/model.pt (the best epoch's weights), out/config.json, out/log.csv. Returns
    {"best_epoch", "best_val", "val_history", "epochs_run", "train_samples", "samples_per_s", ...}.
    """
    import torch
    from tqdm import tqdm

    from predictor.augment import mirror_batch, random_scales, scale_batch
    from predictor.losses import LOSSES, correction, loss_for_epoch, loss_name
    from predictor.models import build_model

    if epochs < 1 or batch_size < 1 or not lr > 0 or warmup_epochs < 0 or (patience is not None and patience < 1):
        raise UserError(f"bad training settings: epochs {epochs}, batch size {batch_size}, lr {lr}, "
                        f"warm-up {warmup_epochs}, patience {patience}; expected positive numbers")
    if not 0 <= scale_jitter < 10:
        raise UserError(f"bad scale jitter {scale_jitter}; expected a fraction in [0, 10), e.g. 0.3")
    if not 0 <= correction_cost < 10:
        raise UserError(f"bad correction cost {correction_cost}; expected a number in [0, 10), e.g. 0.2")
    if mean_loss not in ("nll", "mse", "ade"):
        raise UserError(f"unknown mean loss {mean_loss!r}; expected nll, mse or ade")
    if select not in SELECT:
        raise UserError(f"unknown checkpoint criterion {select!r}; expected one of {', '.join(SELECT)}")
    if lr_schedule not in LR_SCHEDULES:
        raise UserError(f"unknown learning-rate schedule {lr_schedule!r}; expected one of {', '.join(LR_SCHEDULES)}")
    dev = resolve_device(device)
    # One thread unless asked (threads, else OMP_NUM_THREADS): it alone reaches ~1,400 samples/s on this kind of
    # CPU; two are faster only on an idle machine and 4x slower on a shared, loaded one (they spin-wait for a core).
    torch.set_num_threads(threads or int(os.environ.get("OMP_NUM_THREADS", 0)) or 1)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    window = window or WindowConfig()
    key, ids, scenes_fn = open_data(data)  # once: opening checks every shard's sha256
    store = _cached_windows(key, scenes_fn, window, progress, cache_dir)
    split = split_scenes(ids, test_scenes=test_scenes)  # test_scenes: leave-one-scene-out by name
    if progress:
        print(describe_split(split, ids, test_scenes))
    reannotate = tuple(reannotate)
    if reannotate and store.H < 4:  # no lag-1 product of second differences: no noise level for the gate to read
        print(f"note: no re-annotated copies: {store.H} observed steps show the gate no annotation noise")
        reannotate = ()
    if reannotate:
        store = _cached_windows(*_with_copies(key, scenes_fn, split["train"], reannotate, window), window, progress,
                                cache_dir)
    train_idx, val_idx = store.samples_of(split["train"]), store.samples_of(split["val"])
    copies = _copy_table(store, split["train"], reannotate)
    if max_samples is not None and len(train_idx) > max_samples:
        train_idx = np.sort(rng.choice(train_idx, max_samples, replace=False))
    if max_val_samples is not None and len(val_idx) > max_val_samples:  # a fixed subset: comparable epochs
        val_idx = np.sort(np.random.default_rng(seed + 1).choice(val_idx, max_val_samples, replace=False))
    if len(train_idx) == 0 or len(val_idx) == 0:
        raise UserError(f"{data}: no complete {window.history_s:g} s + {window.future_s:g} s windows in the "
                        f"{'train' if len(train_idx) == 0 else 'val'} scenes; record longer scenes")
    mcfg = {"history": store.H, "future": store.F, "max_neighbours": window.max_neighbours,
            "max_horizon": window.max_horizon, "neighbour_grid": window.neighbour_grid,
            "horizon_grid": window.horizon_grid, **(model_config or {})}
    if init is not None:  # fine-tuning continues the network it starts from: its lags and gate
        theirs = read_config(init_files(model, init)[1])["model_config"]
        theirs = theirs if isinstance(theirs, dict) else {}
        mcfg["cv_gate"] = theirs.get("cv_gate", False)
        mcfg["cv_gate_pool"] = theirs.get("cv_gate_pool", False)
        if mcfg.get("cv_lags") == "auto":
            mcfg["cv_lags"] = theirs.get("cv_lags", 1)
    elif mcfg.get("cv_lags") == "auto" and mcfg.get("cv_gate") and mcfg.get("residual"):
        mcfg["cv_lags"] = min(AUTO_LAGS, store.H - 1)  # each track's blend is learned: offer it every lag
    elif mcfg.get("cv_lags") == "auto":  # the lag whose constant velocity fits the training windows best
        mcfg["cv_lags"] = best_cv_lag(store, train_idx, min(AUTO_LAGS, store.H - 1)) if mcfg.get("residual") else 1
    net = build_model(model, mcfg)
    if correction_cost > 0 and (not net.cfg.residual or hasattr(net, "training_step")):
        raise UserError(f"--correction-cost is for the residual form of a model with a plain loss; {model} "
                        f"{'has its own training step' if net.cfg.residual else 'is trained without --residual'}")
    init_info = init_weights(net, model, init) if init is not None else None
    net = net.to(dev)
    opt = torch.optim.Adam(net.parameters(), lr=lr, fused=True)  # one kernel for all parameters
    steps_per_epoch = math.ceil(len(train_idx) / batch_size)
    total_steps = epochs * steps_per_epoch
    warm = max(1, min(steps_per_epoch, round(LR_WARMUP * total_steps)))
    # Per optimiser step (cosine) or per epoch on the validation criterion (plateau).
    sched: Any = (torch.optim.lr_scheduler.LambdaLR(opt, lambda k: lr_factor(k, total_steps, warm))
                  if lr_schedule == "cosine" else None)
    out = Path(out)
    from simharness.io.folders import make_folder, refuse_inside_dataset

    refuse_inside_dataset(out)  # the Python route too: a run folder never lands inside a data set
    make_folder(out)
    config = {"model": model, "model_config": net.cfg.to_dict(), "window": window.to_dict(),
              "frames": {"history": store.H, "future": store.F, "step": store.step},
              "seed": seed, "data": str(data), "data_hash": key, "split": split,
              "train": {"epochs": epochs, "warmup_epochs": warmup_epochs, "batch_size": batch_size, "lr": lr,
                        "max_samples": max_samples, "train_samples": int(len(train_idx)),
                        "val_samples": int(len(val_idx)), "lr_schedule": lr_schedule, "patience": patience,
                        "mean_loss": mean_loss, "select": select, "augment": augment},
              "device": dev.type, "versions": versions()}
    if init_info is not None:
        config["train"]["init"] = init_info
    if scale_jitter > 0:  # only when on: the config hash of every other run stays what it was
        config["train"]["scale_jitter"] = scale_jitter
    if correction_cost > 0:
        config["train"]["correction_cost"] = correction_cost
    if reannotate:
        config["train"]["reannotate"] = [level_name(lv) for lv in reannotate]
    if max_val_samples is not None:
        config["train"]["max_val_samples"] = max_val_samples
    config["config_hash"] = hashlib.sha256(
        json.dumps({k: config[k] for k in ("model", "model_config", "window", "train", "seed")},
                   sort_keys=True).encode()).hexdigest()[:16]
    log = io.StringIO()
    writer = csv.writer(log)
    writer.writerow(["epoch", "loss", "train_loss", "val_mse", "val_nll", "val_rmse_m", "seconds", "samples_per_s",
                     "lr", "val_ade"])
    best, best_epoch, stale = math.inf, -1, 0

    def fitted(epoch: int) -> bool:
        """Whether the weights after `epoch` may be kept: planners read the forecasts' sigma, which only the NLL
        phase fits, so the warm-up's epochs are no candidates (unless no NLL phase, or no sigma: a model without a
        density, Social-GAN, may keep any epoch); starting weights only when trained (`init`)."""
        if epoch == 0:
            return init is not None
        no_sigma = not getattr(net, "gaussian", True)
        return select == "loss" or no_sigma or epoch > warmup_epochs or warmup_epochs >= epochs

    history = [{"epoch": 0, "loss": "init", "train": math.nan, **_epoch_eval(net, store, val_idx, batch_size, dev)}]
    if select != "loss" and fitted(0) and history[0][select] < best:  # trained starting weights are a candidate
        best, best_epoch = history[0][select], 0
        save_checkpoint(net, out / "model.pt")
    measure = "loss" if select == "loss" else select.upper()  # what picks the epoch and stops early, as printed
    if progress:
        stop = (f"; stopping after {patience} epoch{'s' * (patience != 1)} without a better one"
                if patience is not None else "")
        what = "loss (MSE in the warm-up, then NLL)" if select == "loss" else measure
        print(f"choosing the epoch on validation {what} over {len(val_idx)} windows{stop}")
        if best_epoch == 0:
            print(f"starting weights ({init}): validation {measure} {best:.3f}")
    grids = {"nbr": window.neighbour_grid, "hz": window.horizon_grid}
    flips = np.random.default_rng(seed + 2)  # its own stream: the batch order is the same with or without
    scales = np.random.default_rng(seed + 3)
    picks = np.random.default_rng(seed + 4)
    samples_seen, train_time = 0, 0.0
    for epoch in range(epochs):
        kind = loss_for_epoch(epoch, warmup_epochs)
        if epoch == warmup_epochs:  # patience counts NLL-phase epochs only: its first epochs may be worse
            stale = 0
            if select == "loss":
                best = math.inf  # the selection criterion switches from MSE to NLL here
        if lr_schedule == "plateau" and epoch in (0, warmup_epochs):  # a fresh plateau for each criterion
            sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=0)
        epoch_lr = opt.param_groups[0]["lr"]
        order = rng.permutation(train_idx)
        if reannotate:  # each sample from the original or one of its copies
            pick = picks.integers(0, len(reannotate) + 1, len(order))
            order = np.where(pick == 0, order, copies[order, np.maximum(pick - 1, 0)])
        t0, tot, nb = time.perf_counter(), 0.0, 0
        bar = tqdm(range(0, len(order), batch_size), desc=f"epoch {epoch + 1}/{epochs} {kind}", unit="batch",
                   disable=not progress, leave=False)
        for i in bar:
            b = store.batch(order[i:i + batch_size]).tensors()
            if augment:
                b = mirror_batch(b, torch.from_numpy(flips.random(len(b["hist"])) < 0.5), grids)
            if scale_jitter > 0:
                b = scale_batch(b, random_scales(scales, len(b["hist"]), scale_jitter))
            b = _to(b, dev)
            if hasattr(net, "training_step"):  # a model with its own update (Social-GAN: discriminator, variety loss)
                loss = net.training_step(b, kind, opt)
            else:
                fn = LOSSES[loss_name(kind, mean_loss)]
                pred = net(b)
                loss = fn(pred, b["fut"], b["fut_valid"])
                if correction_cost > 0:
                    loss = loss + correction_cost * correction(pred, b["hist"], b["fut_valid"])
                opt.zero_grad()
                loss.backward()
                opt.step()
            if lr_schedule == "cosine":
                sched.step()
            tot += float(loss.detach())
            nb += 1
            if nb % 20 == 0:
                bar.set_postfix(loss=f"{tot / nb:.3f}")
        secs = time.perf_counter() - t0
        samples_seen += len(order)
        train_time += secs
        val = _epoch_eval(net, store, val_idx, batch_size, dev)
        key = kind if select == "loss" else select  # the validation measure this epoch is judged on
        crit = val[key]
        if lr_schedule == "plateau":
            sched.step(crit)
        history.append({"epoch": epoch + 1, "loss": kind, "train": tot / max(nb, 1), **val})
        writer.writerow([epoch + 1, kind, f"{tot / max(nb, 1):.6f}", f"{val['mse']:.6f}", f"{val['nll']:.6f}",
                         f"{math.sqrt(val['mse']):.4f}", f"{secs:.2f}", f"{len(order) / secs:.1f}", f"{epoch_lr:.3g}",
                         f"{val['ade']:.4f}"])
        kept = crit < best and fitted(epoch + 1)
        if kept:
            best, best_epoch, stale = crit, epoch + 1, 0
            save_checkpoint(net, out / "model.pt")
        else:
            stale += 1
        if progress:
            note = " (best so far, kept)" if kept else "" if fitted(epoch + 1) else " (not a candidate)"
            rest = ", ".join(f"{k.upper()} {val[k]:.3f}" for k in ("ade", "mse", "nll") if k != key)
            tqdm.write(f"epoch {epoch + 1}/{epochs}{' warm-up' * (kind == 'mse')}: train "
                       f"{loss_name(kind, mean_loss)} {tot / max(nb, 1):.3f}, validation {key.upper()} {crit:.3f}"
                       f"{note}; {rest}; {len(order) / secs:.0f} samples/s")
        atomic_write_text(out / "log.csv", log.getvalue())
        if patience is not None and epoch >= warmup_epochs and stale >= patience:
            if progress:
                tqdm.write(f"early stop after epoch {epoch + 1}: no better validation {key.upper()} for {stale} "
                           f"epoch{'s' * (stale != 1)} (best: epoch {best_epoch}, {best:.3f})")
            break
    if best_epoch < 0:  # every validation loss was NaN: no checkpoint, so no run folder either
        (out / "log.csv").unlink(missing_ok=True)
        raise UserError(f"{out}: training diverged (validation loss NaN in every epoch); nothing saved: lower --lr")
    config["best_epoch"], config["best_val"], config["epochs_run"] = best_epoch, best, len(history) - 1
    atomic_write_text(out / "config.json", json.dumps(config, indent=1, sort_keys=True) + "\n")
    return {"best_epoch": best_epoch, "best_val": best, "val_history": history, "epochs_run": len(history) - 1,
            "train_samples": int(len(train_idx)), "samples_per_s": samples_seen / max(train_time, 1e-9),
            "out": str(out), "config": config}


def best_cv_lag(store: FeatureStore, idx: np.ndarray, max_lag: int, windows: int = 4000) -> int:
    """The lag l in 1 .. max_lag whose constant-velocity extrapolation (the mean displacement over the last l
    steps) has the lowest ADE on (a fixed subset of `windows` of) the windows idx: 1 on clean tracks, more on
    jittery ones (detected boxes), where the last displacement is mostly noise. `cv_lags = auto` in `train`."""
    import torch

    from predictor.models.gaussian import cv_step, lag_steps

    if max_lag < 2:
        return 1
    if len(idx) > windows:
        idx = np.sort(np.random.default_rng(0).choice(idx, windows, replace=False))
    b = store.batch(idx).tensors()
    hist, fut, valid = b["hist"], b["fut"], b["fut_valid"].float()
    steps = torch.cat([cv_step(hist)[:, None], lag_steps(hist, max_lag)], 1)  # (B, max_lag, 2)
    k = torch.arange(1, fut.shape[1] + 1, dtype=fut.dtype)
    pred = hist[:, -1, None, None, :2] + steps[:, :, None] * k[None, None, :, None]  # (B, L, F, 2)
    err = torch.linalg.norm(pred - fut[:, None], dim=-1)
    ade = (err * valid[:, None]).sum((0, 2)) / valid.sum().clamp_min(1)
    return int(ade.argmin()) + 1


def init_files(model: str, init: str | Path) -> tuple[Path, Path]:
    """(weights, config.json) of `--init`: a run folder, or "shipped" (predictor/weights/<model>); UserError if
    absent."""
    from predictor.predict import WEIGHTS

    if str(init) == "shipped":
        weights, cfg_path = WEIGHTS / f"{model}.pt", WEIGHTS / f"{model}.json"
        if not weights.is_file():
            raise UserError(f"--init shipped: no shipped weights for {model!r} in {WEIGHTS}")
        return weights, cfg_path
    if not Path(init).is_dir():
        raise UserError(f"--init {init}: not a run folder (expected model.pt and config.json), nor 'shipped'")
    return Path(init) / "model.pt", Path(init) / "config.json"


def init_weights(net: Any, model: str, init: str | Path) -> dict[str, Any]:
    """Load `init` (a run folder, or "shipped": predictor/weights/<model>) into `net` -> provenance for config.json.

    UserError (one line) when the checkpoint is of another model or another model config (layer widths, frames,
    residual form...): fine-tuning continues the same network, it does not adapt one."""
    from predictor.checkpoint import load_checkpoint

    weights, cfg_path = init_files(model, init)
    src, cfg = load_checkpoint(weights, cfg_path)
    mine, theirs = net.cfg.to_dict(), src.cfg.to_dict()
    diff = [f"{k} {theirs.get(k)} vs {mine.get(k)}" for k in sorted(set(mine) | set(theirs))
            if mine.get(k) != theirs.get(k)]
    if cfg["model"] != model or diff:
        what = f"model {cfg['model']!r} vs {model!r}" if cfg["model"] != model else ", ".join(diff[:4])
        raise UserError(f"--init {init}: its model config differs from this run's ({what}); train with the "
                        "same model options (--protocol, --residual/--no-residual)")
    net.load_state_dict(src.state_dict())
    return {"from": str(init), "weights_sha256": hashlib.sha256(weights.read_bytes()).hexdigest(),
            "config_hash": cfg.get("config_hash"), "data_hash": cfg.get("data_hash")}


def train_command(args: argparse.Namespace) -> int:
    """`simharness train --data DIR --model NAME --out RUN [...]`."""
    from simharness.io.folders import prepare_output
    from simharness.io.parquet import read_manifest

    # Copies by default where they help: recorded data (a bad folder: one line, nothing written), a gated model.
    gated = bool(getattr(args, "residual", True)) and bool(getattr(args, "cv_gate", True))
    if getattr(args, "init", None) is not None:  # fine-tuning keeps the gate (or none) of the run it continues
        theirs = read_config(init_files(args.model, args.init)[1]).get("model_config") or {}
        gated = bool(theirs.get("residual")) and bool(theirs.get("cv_gate"))
    recorded = not simulated(read_manifest(Path(args.data)).get("info", {}))
    levels = parse_levels(getattr(args, "reannotate_noise", None), getattr(args, "reannotate_smooth", None),
                          recorded and gated, getattr(args, "reannotate_drift", None))
    prepare_output(args.out, getattr(args, "force", False))
    res = train(args.data, model=args.model, out=args.out, epochs=args.epochs, warmup_epochs=args.warmup_epochs,
                batch_size=args.batch_size, lr=args.lr, seed=args.seed, max_samples=args.max_samples,
                max_val_samples=VAL_SAMPLES, test_scenes=getattr(args, "test_scenes", None),
                window=protocol_window(getattr(args, "protocol", None)),
                model_config={"residual": bool(getattr(args, "residual", True)),
                              "cv_lags": getattr(args, "cv_lags", "auto"),
                              "cv_gate": bool(getattr(args, "cv_gate", True)),
                              "cv_gate_pool": bool(getattr(args, "cv_gate_pool", True))},
                lr_schedule=getattr(args, "lr_schedule", "cosine"), patience=getattr(args, "patience", None),
                device=getattr(args, "device", "auto"), mean_loss=getattr(args, "mean_loss", "ade"),
                init=getattr(args, "init", None), select=getattr(args, "select", "ade"),
                augment=getattr(args, "augment", True), scale_jitter=getattr(args, "scale_jitter", 0.0),
                reannotate=levels, correction_cost=getattr(args, "correction_cost", 0.0))
    select = res["config"]["train"]["select"]
    kind = select if select != "loss" else "nll" if res["best_epoch"] > args.warmup_epochs else "mse"
    print(f"{args.model}: kept epoch {res['best_epoch']} of {res['epochs_run']} (validation {kind.upper()} "
          f"{res['best_val']:.3f}), {res['train_samples']} training windows, {res['samples_per_s']:.0f} samples/s "
          f"-> {args.out}")
    more = (f" --protocol {args.protocol}" if getattr(args, "protocol", None) else "") + (
        f" --test-scenes {','.join(args.test_scenes)}" if getattr(args, "test_scenes", None) else "")
    print(f"score the held-out scenes: simharness evaluate --data {args.data} --model {args.out}{more}")
    return 0


def protocol_window(protocol: str | None, **more: Any) -> WindowConfig | None:
    """`--protocol NAME`: training windows of that evaluation protocol's length and rate (None: the default).
    more: other WindowConfig fields (e.g. stride)."""
    if protocol is None:
        return WindowConfig(**more) if more else None
    from simharness.protocols import get_protocol, window_seconds

    return WindowConfig(**window_seconds(get_protocol(protocol)), **more)
