"""Tiles, cores, buffers and neighbouring blocks.

Tiles sit on a global grid of ``tile_size`` metres (so tile names are stable and
neighbouring blocks agree on them). A tile of a block is named ``"{ix}_{iy}"``
with ``ix = floor(x / tile_size)``; its *core* is the block's points in the
half-open square ``[ix*T, (ix+1)*T) × [iy*T, (iy+1)*T)`` — so every point of a
block is in exactly one tile core — and its *buffer* is every point of the
block *and of neighbouring blocks* within ``buffer`` metres of the square that
is not in the core.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

Bounds = tuple[float, float, float, float]  # xmin, ymin, xmax, ymax


def tile_index(x: np.ndarray, tile_size: float) -> np.ndarray:
    """Global grid index of each coordinate."""
    return np.floor(np.asarray(x, dtype=np.float64) / tile_size).astype(np.int64)


def tile_ids(bounds: Bounds, tile_size: float) -> list[str]:
    """Names of the grid tiles a block's bounds touch (row-major, sorted)."""
    xmin, ymin, xmax, ymax = bounds
    ix0, ix1 = math.floor(xmin / tile_size), math.floor(xmax / tile_size)
    iy0, iy1 = math.floor(ymin / tile_size), math.floor(ymax / tile_size)
    return [f"{ix}_{iy}" for iy in range(iy0, iy1 + 1) for ix in range(ix0, ix1 + 1)]


def parse_tile_id(tile: str) -> tuple[int, int]:
    """``"12_34"`` → ``(12, 34)`` (negative indices allowed: ``"-1_5"``)."""
    ix, iy = tile.rsplit("_", 1)
    return int(ix), int(iy)


def tile_bounds(tile: str, tile_size: float) -> Bounds:
    """Core square of a tile."""
    ix, iy = parse_tile_id(tile)
    return (ix * tile_size, iy * tile_size, (ix + 1) * tile_size, (iy + 1) * tile_size)


def expand(bounds: Bounds, margin: float) -> Bounds:
    xmin, ymin, xmax, ymax = bounds
    return (xmin - margin, ymin - margin, xmax + margin, ymax + margin)


def intersects(a: Bounds, b: Bounds) -> bool:
    """Closed-box intersection test."""
    return a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]


def neighbours(block: str, all_bounds: Mapping[str, Bounds], margin: float) -> list[str]:
    """Other blocks whose bounds come within ``margin`` of ``block``'s bounds (sorted)."""
    box = expand(all_bounds[block], margin)
    return sorted(b for b, bb in all_bounds.items() if b != block and intersects(box, bb))


def blocks_for_tile(tile: str, tile_size: float, buffer: float, all_bounds: Mapping[str, Bounds],
                    candidates: Sequence[str] | None = None) -> list[str]:
    """Blocks that may hold points of a tile's core or buffer (sorted)."""
    box = expand(tile_bounds(tile, tile_size), buffer)
    names = all_bounds if candidates is None else candidates
    return sorted(b for b in names if intersects(box, all_bounds[b]))


def core_mask(x: np.ndarray, y: np.ndarray, tile: str, tile_size: float) -> np.ndarray:
    """Points of ``x, y`` inside the tile's half-open core square."""
    ix, iy = parse_tile_id(tile)
    return (tile_index(x, tile_size) == ix) & (tile_index(y, tile_size) == iy)


def box_mask(x: np.ndarray, y: np.ndarray, box: Bounds) -> np.ndarray:
    """Points inside a closed box."""
    return (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
