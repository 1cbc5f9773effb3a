"""Conductor-points files: the wire points of one tile's core, written by its inference job.

Each ``infer_tile`` job also finds its tile's conductor points
(:func:`towerpipe.towers.wires.tile_conductor_points`; the wire search needs only the tile)
and writes them here (``work/{zone}/wires/{block}/{tile}.npz``, :func:`save_conductors`),
so that the search runs in the parallel per-tile jobs; the block's towers job gathers them
(:func:`load_conductors`) into its GeoPackage's ``conductor_points`` layer.

Arrays (float64, one row per point): :data:`CONDUCTOR_ARRAYS`;
``meta``: ``zone``, ``block``, ``tile``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from towerpipe.io.columns import load_columns, save_columns, validate_columns

#: Arrays of a tile's or block's conductor points (float64, one row per point), as
#: :func:`towerpipe.towers.wires.tile_conductor_points` gives them.
CONDUCTOR_ARRAYS: tuple[str, ...] = ("x", "y", "z", "hag", "direction_deg", "clearance_m")

_DTYPES = {k: np.dtype("f8") for k in CONDUCTOR_ARRAYS}
_HINT = "rerun the infer_tile job of the tile (delete the file)"


def save_conductors(path: str | os.PathLike[str], points: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> None:
    """Write one tile's conductor points (:data:`CONDUCTOR_ARRAYS`) and ``meta`` atomically."""
    save_columns(path, {k: np.asarray(points[k], dtype=np.float64) for k in CONDUCTOR_ARRAYS}, meta)


def load_conductors(paths: Sequence[str | os.PathLike[str]]) -> dict[str, np.ndarray]:
    """The conductor points of several tiles, one after the other (:data:`CONDUCTOR_ARRAYS`)."""
    parts = []
    for p in paths:
        arrays, _ = load_columns(p, list(CONDUCTOR_ARRAYS), "conductor-points", _HINT)
        validate_columns(arrays, _DTYPES, p, "conductor-points", _HINT)
        parts.append(arrays)
    return {k: np.concatenate([a[k] for a in parts]) if parts else np.empty(0) for k in CONDUCTOR_ARRAYS}
