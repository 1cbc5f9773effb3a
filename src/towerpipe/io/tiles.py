"""The per-tile intermediate point file: the contract between preprocessing and the model.

A tile file (``.npz``, uncompressed: compressed intermediates cost more time than
they save disk) holds every point of one tile's *core* plus a *buffer* around it
taken from the same block and from neighbouring blocks, with:

================  ========  ====================================================
array             dtype     meaning
================  ========  ====================================================
``x, y, z``       float64   absolute coordinates in the block CRS (metres)
``intensity``     uint16    as in the file
``red, green,     uint16    as in the file (zeros when absent, see ``meta``)
blue, nir``
``classification`` uint8    input class (labels; never used for prediction)
``return_number`` uint8
``number_of_returns`` uint8
``hag``           float32   height above ground (m), from the PDAL DTM
``block_id``      int32     index into ``meta["blocks"]``: the source block
``point_index``   int64     index of the point in its source block file
``core``          bool      the point is owned by this tile (each point of a
                            zone is in exactly one tile core)
``model_input``   bool      the point goes to the model: not ground, not noise
                            (class 7/18), HAG within ``[hag_min, hag_max]``
================  ========  ====================================================

``meta`` is a JSON-able dict: ``zone``, ``block``, ``tile``, ``crs_wkt``,
``core_bounds`` ``[xmin, ymin, xmax, ymax]``, ``buffer``, ``blocks`` (names, the
source block of each ``block_id``), ``has_rgb``, ``has_nir``, ``color_bits``
(8 or 16: how colour is really stored), ``ground_source`` (``"class2"`` or the
PDAL filter used), ``counts`` (points per stage) and ``timings``.

Coordinates stay float64 here; any float32 cast happens after subtracting a
window centre (UTM northings lose ~0.5 m in float32).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from towerpipe.io.columns import load_columns, save_columns, validate_columns

#: Arrays of a tile file and their dtypes, in file order.
TILE_ARRAYS: dict[str, np.dtype] = {
    "x": np.dtype("f8"),
    "y": np.dtype("f8"),
    "z": np.dtype("f8"),
    "intensity": np.dtype("u2"),
    "red": np.dtype("u2"),
    "green": np.dtype("u2"),
    "blue": np.dtype("u2"),
    "nir": np.dtype("u2"),
    "classification": np.dtype("u1"),
    "return_number": np.dtype("u1"),
    "number_of_returns": np.dtype("u1"),
    "hag": np.dtype("f4"),
    "block_id": np.dtype("i4"),
    "point_index": np.dtype("i8"),
    "core": np.dtype("?"),
    "model_input": np.dtype("?"),
}

FORMAT_VERSION = 1


@dataclass
class Tile:
    """Points of one tile (core + buffer) and their metadata.

    Attributes
    ----------
    arrays
        Column arrays named as in :data:`TILE_ARRAYS`, all of the same length.
    meta
        JSON-able metadata (see the module docstring).
    """

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.arrays["x"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def subset(self, mask_or_index: np.ndarray) -> Tile:
        """A new tile with only the selected points (same metadata)."""
        return Tile({k: v[mask_or_index] for k, v in self.arrays.items()}, dict(self.meta))

    def validate(self, path: str | os.PathLike[str] = "<tile>") -> None:
        """Check names, dtypes and lengths; raise :class:`InputError` otherwise."""
        validate_columns(self.arrays, TILE_ARRAYS, path, "tile", "rerun the preprocessing")


def empty_arrays(n: int = 0) -> dict[str, np.ndarray]:
    """Zero-filled tile arrays for ``n`` points."""
    return {k: np.zeros(n, dtype=d) for k, d in TILE_ARRAYS.items()}


def save_tile(path: str | os.PathLike[str], tile: Tile) -> Tile:
    """Write ``tile`` atomically (temporary file, then rename) as uncompressed ``.npz``.

    Returns the tile as :func:`load_tile` reads it back (the same arrays; the metadata as
    stored), for a job that goes on with it in memory.
    """
    tile.validate(path)
    meta = dict(tile.meta, format_version=FORMAT_VERSION)
    save_columns(path, tile.arrays, meta)
    return Tile({k: tile.arrays[k] for k in TILE_ARRAYS}, json.loads(json.dumps(meta)))


def load_tile(path: str | os.PathLike[str], columns: list[str] | None = None) -> Tile:
    """Read a tile file written by :func:`save_tile`.

    Parameters
    ----------
    path
        The ``.npz`` file.
    columns
        Only these arrays (default: all).
    """
    arrays, meta = load_columns(
        path, list(TILE_ARRAYS) if columns is None else columns, "tile", "rerun the preprocessing"
    )
    tile = Tile(arrays, meta)
    if columns is None:
        tile.validate(path)
    return tile


def labelled_points(paths: list[str] | tuple[str, ...], label: int) -> dict[str, np.ndarray]:
    """The points of tile files whose input class is ``label``, core and buffer, each point once.

    A block's tiles, with the buffers their neighbours lent them, hold whole the labelled
    objects that cross the block's edges (a tower on the seam of two blocks); a point in
    several tiles (buffers overlap) is kept once, by its source block and ``point_index``.
    Only the class column of a tile is read whole; ``x, y, z, hag`` (float64) of the labelled
    points are returned, in no particular order.
    """
    keys, parts = [], []
    for p in paths:
        cls = load_tile(p, columns=["classification"]).arrays["classification"]
        sel = np.flatnonzero(cls == label)
        if not len(sel):
            continue
        t = load_tile(p, columns=["x", "y", "z", "hag", "block_id", "point_index"])
        names = np.asarray(t.meta["blocks"], dtype=object)
        keys += list(zip(names[t.arrays["block_id"][sel]].tolist(), t.arrays["point_index"][sel].tolist(), strict=True))
        parts.append({k: np.asarray(t.arrays[k][sel], np.float64) for k in ("x", "y", "z", "hag")})
    out = {k: np.concatenate([q[k] for q in parts]) if parts else np.zeros(0) for k in ("x", "y", "z", "hag")}
    first: dict[tuple[str, int], int] = {}
    for i, key in enumerate(keys):
        first.setdefault(key, i)
    keep = np.fromiter(first.values(), dtype=np.int64, count=len(first))
    return {k: v[keep] for k, v in out.items()}
