"""The model as inference sees it: the :class:`BundleLike` protocol, whether a tile's data
can feed a model (:func:`check_model_compatibility`), and the model's record in a
prediction file's meta (:func:`model_info`).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from towerpipe.errors import ModelError

__all__ = ["BundleLike", "check_model_compatibility", "model_info"]


class BundleLike(Protocol):
    """The part of :class:`towerpipe.model.bundle.ModelBundle` inference uses."""

    name: str
    version: str
    feature_set: str
    card: dict[str, Any]
    n_points: int

    def classify(self, feats: np.ndarray) -> np.ndarray: ...  # (B, n, C) -> (B,)

    def segment(self, feats: np.ndarray) -> np.ndarray: ...  # (N, C) -> (N,)


def check_model_compatibility(tile_meta: Mapping[str, Any], bundle: BundleLike) -> None:
    """Raise :class:`ModelError` when the tile lacks valid attributes the model's features need.

    Parameters
    ----------
    tile_meta
        Tile metadata (``valid_attributes``, ``tile``, ``block``).
    bundle
        The model bundle (its ``feature_set`` decides the needed attributes).

    Raises
    ------
    ModelError
        Naming the missing attributes, the model, and the config key that chooses a model.
    """
    from towerpipe.model import features

    try:
        missing = features.missing_attributes(bundle.feature_set, tile_meta)
    except ModelError as exc:
        raise ModelError(f"model {bundle.name!r} v{bundle.version}: {exc}") from exc
    if missing:
        where = f"block {tile_meta.get('block', '?')!r} tile {tile_meta.get('tile', '?')!r}"
        raise ModelError(
            f"{where} has no valid {', '.join(missing)} but model {bundle.name!r} v{bundle.version} "
            f"(feature set {bundle.feature_set!r}) needs {', '.join(features.required_attributes(bundle.feature_set))}; "
            f"set `inference: {{model: auto}}` (or the zone's `model: auto`) to use a model these data support"
        )


def model_info(bundle: BundleLike, model_path: str | os.PathLike[str] | None) -> dict[str, Any]:
    path = model_path if model_path is not None else getattr(bundle, "path", None)
    files = (bundle.card or {}).get("files") if isinstance(getattr(bundle, "card", None), Mapping) else None
    sha = None
    if isinstance(files, Mapping) and files:
        sha = hashlib.sha256("".join(f"{k}:{files[k]}" for k in sorted(files)).encode()).hexdigest()
    return {
        "name": bundle.name,
        "version": str(bundle.version),
        "feature_set": bundle.feature_set,
        "path": None if path is None else str(path),
        "sha256": sha,
    }
