"""Training the classifier and the segmenter, and writing a checkpoint bundle.

As in Carós et al. (2022, sec. 5.1): class-balanced NLL (effective number of samples,
``beta``), Adam at 1e-3, learning rate halved when the validation loss has not improved
for 10 epochs, at most 50 epochs with early stopping on the validation loss (the best
epoch's weights are kept), batches of 32 windows of 2048 points. ``lr_schedule:
onecycle`` instead raises the rate to ``max_lr`` over the first 30 % of the planned
steps and anneals it (one cycle), which converges in a few epochs on a CPU budget. The classifier trains
on every training window; the segmenter on the positive windows plus
``seg_negatives_per_positive`` negative windows per positive, drawn first from the
hard negatives (a positive window with its tower removed) and the tall negatives
(centred on a tall non-tower object), so that a window wrongly passed by the gate does
not produce tower points (a production addition; the paper trains on positives).
Augmentation (:mod:`towerpipe.training.augment`): rotation about z, scale, coordinate jitter, and
attribute dropout and corruption (``attribute_corruption``, the chance per window and
attribute group) so that no model collapses when a column carries nothing.
``exclude_families`` leaves the windows of some real tower families out of every split
(the leave-one-source-out benchmark).

Window and point scores are in :mod:`towerpipe.training.metrics`, the model card and loss
curves in :mod:`towerpipe.training.card`, the ``towerpipe train`` command in
:mod:`towerpipe.training.cli`. Entry points take plain paths and dicts::

    from towerpipe.training.train import train_bundle
    train_bundle(["work/train/tiles/b1/t1.npz", ...], "results/models/towerpipe-full-v2", "full",
                 {"epochs": 12})
"""

from __future__ import annotations

import copy
import json
import logging
import math
import os
import re
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from towerpipe.errors import ConfigError
from towerpipe.model.bundle import load_bundle, save_bundle
from towerpipe.model.features import FEATURE_SETS, required_attributes
from towerpipe.model.pointnet import PointNetClassifier, PointNetSegmenter, build_model, count_parameters
from towerpipe.progress import peak_rss_mb
from towerpipe.training.augment import augment_geometry, corrupt_attributes
from towerpipe.training.card import make_card, save_curves
from towerpipe.training.dataset import load_or_build
from towerpipe.training.losses import class_balanced_weights, feature_transform_regulariser, weighted_nll
from towerpipe.training.metrics import classification_metrics, predict_windows, segment_windows_metrics
from towerpipe.training.windowset import FAMILY_BITS, KINDS, WindowSet

log = logging.getLogger(__name__)

DEFAULT_TRAIN_CONFIG: dict[str, Any] = {
    "feature_set": "full",
    "arch": "light",
    "sampling": "constrained",
    "beta": 0.999,
    "seed": 0,
    "epochs": 50,
    "early_stop_patience": 10,
    "batch_size": 32,
    "lr": 1e-3,
    "lr_factor": 0.5,
    "lr_patience": 10,
    "lr_schedule": "plateau",
    "max_lr": 3e-3,
    "ft_reg": 0.001,
    "rotate": True,
    "jitter_m": 0.05,
    "scale": 0.0,
    "attribute_corruption": 0.0,
    "exclude_families": [],
    "seg_negatives_per_positive": 0.5,
    "init_from": None,
    "max_train_windows": None,
    "time_budget_s": None,
    "threads": 2,
    "threshold": 0.5,
    "eval_chunk": 65536,
    "progress": None,
}


def train_config(config: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Defaults updated with ``config``; ``dataset`` (a dict) is passed to the dataset builder."""
    out = dict(DEFAULT_TRAIN_CONFIG)
    for k, v in (config or {}).items():
        if k == "dataset":
            continue
        if k not in out:
            raise ConfigError(f"train config: unknown key {k!r}; known: {sorted(out) + ['dataset']}")
        out[k] = v
    if out["feature_set"] not in FEATURE_SETS:
        raise ConfigError(f"train config: feature_set {out['feature_set']!r} not in {sorted(FEATURE_SETS)}")
    if out["sampling"] not in ("constrained", "random"):
        raise ConfigError("train config: sampling must be 'constrained' or 'random'")
    if out["lr_schedule"] not in ("plateau", "onecycle"):
        raise ConfigError("train config: lr_schedule must be 'plateau' (the paper's) or 'onecycle'")
    return out


def _augment(x: np.ndarray, labels: np.ndarray, cfg: Mapping[str, Any], rng: np.random.Generator) -> np.ndarray:
    """Geometry and attribute augmentation of sampled windows ``(B, n, C)`` (:mod:`towerpipe.training.augment`)."""
    augment_geometry(x, cfg, rng)
    return corrupt_attributes(x, FEATURE_SETS[cfg["feature_set"]], labels, float(cfg["attribute_corruption"]), rng)


def kept_windows(windows: WindowSet, split: str, cfg: Mapping[str, Any]) -> np.ndarray:
    """The windows of a split, without those holding a tower of an excluded family."""
    idx = windows.indices(split)
    bits = 0
    for f in cfg["exclude_families"]:
        if f not in FAMILY_BITS:
            raise ConfigError(f"train config: exclude_families: unknown family {f!r}; known: {sorted(FAMILY_BITS)}")
        bits |= FAMILY_BITS[f]
    return idx[(windows.family[idx] & bits) == 0] if bits else idx


def _progress(total: int, desc: str, cfg: Mapping[str, Any]):
    from tqdm import tqdm

    disable = not sys.stderr.isatty() if cfg["progress"] is None else not cfg["progress"]
    return tqdm(total=total, desc=desc, disable=disable, leave=False)


def _fit(
    model: torch.nn.Module,
    ws: WindowSet,
    train_idx: np.ndarray,
    val_idx: np.ndarray,
    weights: np.ndarray,
    cfg: Mapping[str, Any],
    per_point: bool,
    desc: str,
) -> tuple[torch.nn.Module, list[dict[str, float]], dict[str, Any]]:
    """Shared training loop; returns the best-validation model, history and run info."""
    rng = np.random.default_rng(int(cfg["seed"]))
    torch.manual_seed(int(cfg["seed"]))
    torch.set_num_threads(int(cfg["threads"]))
    w = torch.tensor(weights, dtype=torch.float32)
    opt = torch.optim.Adam(model.parameters(), lr=float(cfg["lr"]))
    plateau = cfg["lr_schedule"] == "plateau"
    if plateau:
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt, factor=float(cfg["lr_factor"]), patience=int(cfg["lr_patience"])
        )
    else:  # one cycle over the planned epochs: up to max_lr, then annealed (converges in few epochs)
        per_epoch = max(
            1,
            sum(
                1
                for s in range(0, len(train_idx), int(cfg["batch_size"]))
                if len(train_idx[s : s + int(cfg["batch_size"])]) > 1
            ),
        )
        sched = torch.optim.lr_scheduler.OneCycleLR(
            opt, max_lr=float(cfg["max_lr"]), pct_start=0.3, total_steps=int(cfg["epochs"]) * per_epoch
        )
    fs, samp, bs = cfg["feature_set"], cfg["sampling"], int(cfg["batch_size"])
    history: list[dict[str, float]] = []
    best = (math.inf, -1, copy.deepcopy(model.state_dict()))
    t0 = time.perf_counter()
    n_batches = 0
    stopped = "epochs"

    def target(lab: np.ndarray, i: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(lab if per_point else ws.label[i].astype(np.int64))

    for epoch in range(int(cfg["epochs"])):
        model.train()
        order = rng.permutation(train_idx)
        batches = [order[s : s + bs] for s in range(0, len(order), bs)]
        batches = [b for b in batches if len(b) > 1]  # batch norm needs > 1 sample
        tot, cnt = 0.0, 0
        with _progress(len(batches), f"{desc} epoch {epoch + 1}", cfg) as bar:
            for b in batches:
                x, lab = ws.sampled(b, fs, samp)
                x = torch.from_numpy(_augment(x, lab, cfg, rng))
                logp, t_feat = model(x)
                loss = weighted_nll(logp, target(lab, b), w)
                if cfg["ft_reg"] and t_feat is not None:  # PointNet's feature transform
                    loss = loss + float(cfg["ft_reg"]) * feature_transform_regulariser(t_feat)
                opt.zero_grad()
                loss.backward()
                opt.step()
                if not plateau:
                    sched.step()
                tot += float(loss.detach()) * len(b)
                cnt += len(b)
                n_batches += 1
                bar.update(1)
        val_loss = _eval_loss(model, ws, val_idx, w, cfg, per_point)
        if not math.isfinite(val_loss):  # no validation windows: fall back to the training loss
            val_loss = tot / max(cnt, 1)
        if plateau:
            sched.step(val_loss)
        rec = {
            "epoch": epoch + 1,
            "train_loss": tot / max(cnt, 1),
            "val_loss": val_loss,
            "lr": opt.param_groups[0]["lr"],
            "elapsed_s": time.perf_counter() - t0,
        }
        history.append(rec)
        log.info("%s epoch %d: train %.4f val %.4f", desc, epoch + 1, rec["train_loss"], val_loss)
        if val_loss < best[0]:
            best = (val_loss, epoch, copy.deepcopy(model.state_dict()))
        elif epoch - best[1] >= int(cfg["early_stop_patience"]):
            stopped = "early_stopping"
            break
        if cfg["time_budget_s"] and time.perf_counter() - t0 > float(cfg["time_budget_s"]):
            stopped = "time_budget"
            break
    model.load_state_dict(best[2])
    model.eval()
    elapsed = time.perf_counter() - t0
    info = {
        "train_time_s": elapsed,
        "batches": n_batches,
        "s_per_batch": elapsed / max(n_batches, 1),
        "best_epoch": best[1] + 1,
        "epochs_run": len(history),
        "stopped_by": stopped,
        "class_weights": [float(v) for v in weights],
        "parameters": count_parameters(model),
    }
    return model, history, info


@torch.inference_mode()
def _eval_loss(
    model: torch.nn.Module, ws: WindowSet, idx: np.ndarray, w: torch.Tensor, cfg: Mapping[str, Any], per_point: bool
) -> float:
    if len(idx) == 0:
        return float("nan")
    model.eval()
    tot, cnt = 0.0, 0
    for s in range(0, len(idx), 64):
        b = idx[s : s + 64]
        x, lab = ws.sampled(b, cfg["feature_set"], cfg["sampling"])
        logp, _ = model(torch.from_numpy(x))
        t = torch.from_numpy(lab if per_point else ws.label[b].astype(np.int64))
        tot += float(weighted_nll(logp, t, w)) * len(b)
        cnt += len(b)
    return tot / cnt


def _subset(idx: np.ndarray, n: int | None, rng: np.random.Generator) -> np.ndarray:
    return idx if not n or len(idx) <= n else np.sort(rng.choice(idx, int(n), replace=False))


def _initial(kind: str, cfg: Mapping[str, Any], n_features: int) -> torch.nn.Module:
    """A fresh network, or a copy of the ``kind`` network of bundle ``cfg["init_from"]`` (warm start)."""
    hp = {
        "kind": kind,
        "in_channels": n_features,
        "arch": cfg["arch"],
        "k": 2,
        "dropout": 0.3 if kind == "classifier" else 0.0,
    }
    if not cfg["init_from"]:
        return build_model(hp)
    bundle = load_bundle(cfg["init_from"])
    if bundle.feature_set != cfg["feature_set"]:
        raise ConfigError(
            f"train: init_from {cfg['init_from']} is a {bundle.feature_set!r} model, this trains "
            f"{cfg['feature_set']!r}; start from a bundle of the same feature set or set init_from: null"
        )
    net = build_model(hp)
    net.load_state_dict(getattr(bundle, kind).state_dict())
    return net


def train_classifier(
    windows: WindowSet, config: Mapping[str, Any] | None = None
) -> tuple[PointNetClassifier, list[dict[str, float]], dict[str, Any]]:
    """Train the window classifier.

    Parameters
    ----------
    windows
        Built windows (:func:`towerpipe.training.dataset.build_windows`).
    config
        Overrides of :data:`DEFAULT_TRAIN_CONFIG`.

    Returns
    -------
    tuple
        ``(model in eval mode, per-epoch history, metrics)``; metrics hold ``val`` and
        ``test`` F1/precision/recall/accuracy, the class weights, time and peak memory.
    """
    cfg = train_config(config)
    rng = np.random.default_rng(int(cfg["seed"]))
    train_idx = _subset(kept_windows(windows, "train", cfg), cfg["max_train_windows"], rng)
    if len(train_idx) < 2:
        raise ConfigError("train: fewer than 2 training windows; build a larger dataset")
    counts = np.bincount(windows.label[train_idx], minlength=2)
    weights = class_balanced_weights(counts, float(cfg["beta"]))
    torch.manual_seed(int(cfg["seed"]))
    model = _initial("classifier", cfg, len(FEATURE_SETS[cfg["feature_set"]]))
    model, history, info = _fit(
        model, windows, train_idx, kept_windows(windows, "val", cfg), weights, cfg, False, "classifier"
    )
    metrics: dict[str, Any] = dict(info, train_counts=[int(c) for c in counts])
    for split in ("val", "test"):
        idx = kept_windows(windows, split, cfg)
        prob = predict_windows(model, windows, idx, cfg["feature_set"], cfg["sampling"])
        metrics[split] = classification_metrics(prob, windows.label[idx], float(cfg["threshold"]))
    metrics["peak_rss_mb"] = peak_rss_mb()
    return model, history, metrics


def train_segmenter(
    windows: WindowSet, config: Mapping[str, Any] | None = None
) -> tuple[PointNetSegmenter, list[dict[str, float]], dict[str, Any]]:
    """Train the per-point segmenter on positive windows (+ a fraction of negatives).

    Test metrics (IoU tower, IoU background, mIoU) are computed on *all* points of the
    test positive windows, as at inference (:func:`towerpipe.model.folded.segment_points`).
    """
    cfg = train_config(config)
    rng = np.random.default_rng(int(cfg["seed"]) + 1)

    def pick(split: str) -> np.ndarray:
        idx = kept_windows(windows, split, cfg)
        pos = idx[windows.label[idx] == 1]
        neg = idx[windows.label[idx] == 0]
        hard = np.isin(windows.kind[neg], [KINDS["hard_negative"], KINDS["tall_negative"]])
        k = min(len(neg), int(round(float(cfg["seg_negatives_per_positive"]) * len(pos))))
        first = rng.permutation(neg[hard])
        chosen = np.concatenate([first, rng.permutation(neg[~hard])])[:k]
        return np.sort(np.concatenate([pos, chosen]))

    train_idx = _subset(pick("train"), cfg["max_train_windows"], rng)
    if len(train_idx) < 2:
        raise ConfigError("train: fewer than 2 segmentation training windows (positives); build a larger dataset")
    _, lab = windows.sampled(train_idx, cfg["feature_set"], cfg["sampling"])
    counts = np.bincount(lab.ravel(), minlength=2)
    weights = class_balanced_weights(counts, float(cfg["beta"]))
    torch.manual_seed(int(cfg["seed"]))
    model = _initial("segmenter", cfg, len(FEATURE_SETS[cfg["feature_set"]]))
    model, history, info = _fit(model, windows, train_idx, pick("val"), weights, cfg, True, "segmenter")
    metrics: dict[str, Any] = dict(info, train_point_counts=[int(c) for c in counts])
    for split in ("val", "test"):
        metrics[split] = segment_windows_metrics(
            model,
            windows,
            kept_windows(windows, split, cfg),
            cfg["feature_set"],
            float(cfg["threshold"]),
            int(cfg["eval_chunk"]),
        )
    metrics["peak_rss_mb"] = peak_rss_mb()
    return model, history, metrics


def train_bundle(
    dataset_paths: Sequence[str | os.PathLike[str]] | str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    feature_set: str = "full",
    config: Mapping[str, Any] | None = None,
) -> Path:
    """Build/load windows, train classifier + segmenter and write a checkpoint directory.

    Parameters
    ----------
    dataset_paths
        Labelled tile files, or one windows ``.npz`` (:meth:`WindowSet.save`).
    out_dir
        Checkpoint directory to write (``classifier.pt``, ``segmenter.pt``, model card,
        ``classifier_curves.png``, ``segmenter_curves.png``, ``history.json``).
    feature_set
        ``"full"`` or ``"geometry"``.
    config
        Training overrides (:data:`DEFAULT_TRAIN_CONFIG`); key ``dataset`` holds dataset
        overrides (:data:`towerpipe.training.dataset.DEFAULT_DATASET_CONFIG`); optional
        ``classifier`` / ``segmenter`` sub-dicts override per network.

    Returns
    -------
    pathlib.Path
        ``out_dir``.
    """
    config = dict(config or {})
    per_net = {k: dict(config.pop(k, {}) or {}) for k in ("classifier", "segmenter")}
    ws = load_or_build(dataset_paths, config.get("dataset"))
    config["feature_set"] = feature_set
    cfg = train_config(config)
    if ws.meta.get("valid_attributes") is not None:  # valid on every training block, not only present
        lacking = [a for a in required_attributes(feature_set) if a not in ws.meta["valid_attributes"]]
    else:  # windows built before the blocks' attributes were recorded: presence only
        lacking = [
            a
            for a, flag in (("rgb", "has_rgb"), ("nir", "has_nir"))
            if a in required_attributes(feature_set) and not ws.meta.get(flag)
        ]
    if lacking:
        raise ConfigError(
            f"train: feature set {feature_set!r} needs {', '.join(lacking)} valid on every training block, "
            "but some blocks lack it or carry it degenerate (all 0, constant: their QA pages say which); "
            "use a feature set without it (e.g. --feature-set shape)"
        )
    out = Path(out_dir)
    # the name and release from the directory name (``towerpipe-shape-v3``, ``towerpipe-shape-v3-without-uav``),
    # decided before hours of training rather than after; a directory named otherwise names the
    # model itself, release 0: never taken for a shipped model (``towerpipe-shape`` v3)
    release = re.search(r"-v(\d+)(?:-without-[a-z0-9]+)?$", out.name)
    version = release.group(1) if release else "0"
    out.mkdir(parents=True, exist_ok=True)
    clf, h_clf, m_clf = train_classifier(ws, {**cfg, **per_net["classifier"]})
    seg, h_seg, m_seg = train_segmenter(ws, {**cfg, **per_net["segmenter"]})
    save_curves(h_clf, out / "classifier_curves.png", f"classifier ({feature_set})")
    save_curves(h_seg, out / "segmenter_curves.png", f"segmenter ({feature_set})")
    (out / "history.json").write_text(json.dumps({"classifier": h_clf, "segmenter": h_seg}, indent=1))
    card = make_card(
        feature_set,
        ws,
        {**cfg, "per_network": per_net},
        m_clf,
        m_seg,
        name=_bundle_name(out.name) or out.name,
        version=version,
    )
    save_bundle(out, clf, seg, card)
    log.info(
        "wrote %s: classifier test F1 %.3f, segmenter test mIoU %.3f", out, m_clf["test"]["f1"], m_seg["test"]["miou"]
    )
    return out


def _bundle_name(dirname: str) -> str | None:
    """``towerpipe-shape-v3-without-uav`` -> ``towerpipe-shape-without-uav``; ``None`` for a name without a release."""
    m = re.match(r"^(.*)-v\d+(-without-[a-z0-9]+)?$", dirname)
    return f"{m.group(1)}{m.group(2) or ''}" if m else None
