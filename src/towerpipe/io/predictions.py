"""The per-tile prediction file: the contract between inference and the block products.

A prediction file (``work/{zone}/pred/{block}/{tile}.npz``, uncompressed, written
atomically) holds only the tile's **core** points that were inside at least one
segmented window; every other point has tower probability 0 by definition.

================  ========  ====================================================
array             dtype     meaning
================  ========  ====================================================
``block_id``      int32     index into ``meta["blocks"]`` (same as the tile file)
``point_index``   int64     index of the point in its source block file
``x, y, z``       float64   absolute coordinates
``hag``           float32   height above ground (m)
``prob``          float32   tower probability, averaged over the views of each
                            window (``inference.tta``), overlapping windows
                            combined per point: ``TowerProbability``; the points
                            of a tower are those at or above ``inference.threshold``
``prob_single``   float32   the same from the window as it is (one view): towers
                            are found and tested on it (:mod:`towerpipe.towers.extract`);
                            equal to ``prob`` with one view
================  ========  ====================================================

``meta`` is a JSON-able dict: ``zone``, ``block``, ``tile``, ``blocks``,
``crs_wkt``, ``core_bounds``, ``model`` (``name``, ``version``, ``feature_set``,
``path``, ``sha256``), ``windows_total``, ``windows_passed_gate``,
``windows_segmented``, ``gate_threshold``, ``combine``, ``points_core``,
``points_model_input_core``, ``timings`` (seconds), ``peak_rss_mb`` and ``window_gates``
(what the gates made of every window: :func:`towerpipe.inference.windows.window_gates`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.errors import InputError
from towerpipe.io.columns import load_columns, save_columns, validate_columns

#: Arrays of a prediction file and their dtypes, in file order.
PRED_ARRAYS: dict[str, np.dtype] = {
    "block_id": np.dtype("i4"),
    "point_index": np.dtype("i8"),
    "x": np.dtype("f8"),
    "y": np.dtype("f8"),
    "z": np.dtype("f8"),
    "hag": np.dtype("f4"),
    "prob": np.dtype("f4"),
    "prob_single": np.dtype("f4"),
}

#: Keys every prediction file's ``meta`` carries.
PRED_META_KEYS: tuple[str, ...] = (
    "zone",
    "block",
    "tile",
    "blocks",
    "crs_wkt",
    "core_bounds",
    "model",
    "windows_total",
    "windows_passed_gate",
    "windows_segmented",
    "gate_threshold",
    "combine",
    "points_core",
    "points_model_input_core",
    "timings",
    "peak_rss_mb",
)

FORMAT_VERSION = 2  # 2: prob_single


@dataclass
class PredFile:
    """Tower probabilities of one tile's core points and their metadata.

    Attributes
    ----------
    arrays
        Column arrays named as in :data:`PRED_ARRAYS`, all of the same length.
    meta
        JSON-able metadata (see the module docstring).
    """

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.arrays["prob"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def for_block(self, block: str) -> dict[str, np.ndarray]:
        """The arrays restricted to points whose source block is ``block``.

        Returns empty arrays when the block is not among ``meta["blocks"]``.
        """
        blocks = list(self.meta.get("blocks", []))
        if block not in blocks:
            return {k: v[:0] for k, v in self.arrays.items()}
        sel = self.arrays["block_id"] == blocks.index(block)
        return {k: v[sel] for k, v in self.arrays.items()}

    def validate(self, path: str | os.PathLike[str] = "<pred>") -> None:
        """Check names, dtypes, lengths and meta keys; raise :class:`InputError` otherwise."""
        validate_columns(self.arrays, PRED_ARRAYS, path, "prediction", "rerun the inference")
        missing_meta = [k for k in PRED_META_KEYS if k not in self.meta]
        if missing_meta:
            raise InputError(path, f"prediction file meta lacks {missing_meta}; rerun the inference")


def empty_pred_arrays(n: int = 0) -> dict[str, np.ndarray]:
    """Zero-filled prediction arrays for ``n`` points."""
    return {k: np.zeros(n, dtype=d) for k, d in PRED_ARRAYS.items()}


def one_view_default(arrays: Mapping[str, np.ndarray]) -> Mapping[str, np.ndarray]:
    """``arrays`` with ``prob_single``: a prediction without it is one view, ``prob`` itself."""
    if "prob_single" in arrays or "prob" not in arrays:
        return arrays
    return {**arrays, "prob_single": arrays["prob"]}


def save_pred(
    path: str | os.PathLike[str],
    arrays: Mapping[str, np.ndarray],
    meta: Mapping[str, Any],
) -> None:
    """Write a prediction file atomically (``<path>.part``, then rename), uncompressed.

    Parameters
    ----------
    path
        Destination ``.npz``.
    arrays
        Arrays named as in :data:`PRED_ARRAYS` (cast to the contract dtypes); without
        ``prob_single``, the prediction is one view and ``prob`` is used for it.
    meta
        JSON-able metadata with at least :data:`PRED_META_KEYS`.
    """
    path = Path(path)
    cast = {}
    arrays = one_view_default(arrays)
    for name, dtype in PRED_ARRAYS.items():
        if name not in arrays:
            raise InputError(path, f"prediction array {name!r} missing")
        cast[name] = np.ascontiguousarray(np.asarray(arrays[name]).astype(dtype, copy=False))
    pred = PredFile(cast, dict(meta))
    pred.validate(path)
    save_columns(path, cast, dict(meta, format_version=FORMAT_VERSION))


def load_pred(path: str | os.PathLike[str]) -> PredFile:
    """Read and validate a prediction file written by :func:`save_pred`."""
    arrays, meta = load_columns(path, list(PRED_ARRAYS), "prediction", "rerun the inference")
    pred = PredFile(arrays, meta)
    pred.validate(path)
    return pred
