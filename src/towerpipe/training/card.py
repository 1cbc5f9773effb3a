"""The model card and the loss curves of a trained bundle.

:func:`make_card` writes what :mod:`towerpipe.model.cards` reads: features, architecture,
sampling, training data, metrics, the bundle a warm start began from (:func:`init_record`)
and the configuration's hash; :func:`save_curves` plots the loss per epoch.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from towerpipe.model.cards import BUNDLE_VERSION, MODEL_RELEASES
from towerpipe.model.features import FEATURE_SETS, normalisation_spec
from towerpipe.training.dataset import DEFAULT_DATASET_CONFIG
from towerpipe.training.windowset import WindowSet


def init_record(init_from: str | os.PathLike[str] | None) -> dict[str, Any] | None:
    """What a warm-started bundle started from: name, version and weight hashes of ``init_from``."""
    if not init_from:
        return None
    from towerpipe.model import cards as modelcard

    card = modelcard.read_card(init_from)
    return {
        "path": str(init_from),
        "name": card.get("name"),
        "version": card.get("version"),
        "files_sha256": card.get("files"),
        "config_hash": card.get("config_hash"),
    }


def save_curves(history: Sequence[Mapping[str, float]], path: str | os.PathLike[str], title: str) -> Path:
    """Plot train/validation loss and learning rate per epoch to a PNG (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = [h["epoch"] for h in history]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(ep, [h["train_loss"] for h in history], "o-", label="train loss")
    ax.plot(ep, [h["val_loss"] for h in history], "s-", label="validation loss")
    ax.set_xlabel("epoch")
    ax.set_ylabel("weighted NLL")
    ax.set_title(title)
    ax2 = ax.twinx()
    ax2.plot(ep, [h["lr"] for h in history], ":", color="grey", label="learning rate")
    ax2.set_ylabel("learning rate")
    ax.legend(loc="upper right")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def make_card(
    feature_set: str,
    windows: WindowSet,
    config: Mapping[str, Any],
    clf_metrics: Mapping[str, Any],
    seg_metrics: Mapping[str, Any],
    name: str | None = None,
    version: str | None = None,
) -> dict[str, Any]:
    """The model card of a trained bundle (see :mod:`towerpipe.model.cards`).

    ``version`` defaults to the shipped release of ``feature_set``
    (:data:`towerpipe.model.cards.MODEL_RELEASES`).
    """
    from towerpipe.model import cards as modelcard

    dcfg = windows.meta.get("config", DEFAULT_DATASET_CONFIG)
    full_config = {"train": dict(config), "dataset": dcfg}
    return {
        "name": name or f"towerpipe-{feature_set}",
        "version": str(version or MODEL_RELEASES[feature_set]),
        "bundle_version": BUNDLE_VERSION,
        "feature_set": feature_set,
        "features": FEATURE_SETS[feature_set],
        "architecture": {
            "arch": config["arch"],
            "classifier_parameters": clf_metrics.get("parameters"),
            "segmenter_parameters": seg_metrics.get("parameters"),
        },
        "normalisation": normalisation_spec(),
        "sampling": {
            "n_points": windows.n_points,
            "training": config["sampling"],
            "bands_m": dcfg.get("bands"),
            "padding": "all points once + uniform draws with replacement",
            "inference_classifier": "constrained sample of n_points",
            "inference_segmenter": "all points of the window",
        },
        "training_data": {
            "tiles": windows.meta.get("tiles", []),
            "blocks_split": windows.meta.get("split", {}),
            "towers": windows.meta.get("towers"),
            "summary": windows.meta.get("summary"),
            "has_rgb": windows.meta.get("has_rgb"),
            "has_nir": windows.meta.get("has_nir"),
        },
        "metrics": {"classifier": dict(clf_metrics), "segmenter": dict(seg_metrics)},
        "init_from": init_record(config.get("init_from")),
        "code": modelcard.code_version(),
        "config_hash": modelcard.config_hash(full_config),
        "config": full_config,
        "created_unix": int(time.time()),
    }
