"""The points around each tower of a block, for its side views on the QA page.

:func:`tower_neighbourhoods` cuts a square around each tower from the block's tiles (core
and buffer, each point once, noise left out) and marks the towers' own points; the side
views are drawn by :func:`towerpipe.products.qa.plots.tower_elevations`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

#: Half-width (m) of the square around a tower shown in its side views, at least.
VIEW_RADIUS_M = 30.0


def tower_neighbourhoods(
    tile_files: Sequence[str | os.PathLike[str]],
    member_files: Sequence[str | os.PathLike[str]],
    towers: Any,
    radius: float = VIEW_RADIUS_M,
) -> dict[str, dict[str, np.ndarray]]:
    """The points around each tower, for its side views.

    Parameters
    ----------
    tile_files
        The block's tile files: core and buffer, so a tower across a block edge is seen
        whole (its neighbour's points are in the buffer).
    member_files
        Tower-points files (:func:`towerpipe.io.members.save_members`): which points are the
        towers' own (the points the merge classifies 15).
    towers
        The block's towers (GeoDataFrame with ``tower_id``, ``centroid_x``, ``centroid_y``).
    radius
        Half-width of the square around each tower's centroid (grown to hold the whole
        footprint and 15 m around it).

    Returns
    -------
    dict
        ``tower_id`` → ``x, y, z`` (float64) and ``tower`` (bool) of the points in its square,
        without the noise (:func:`towerpipe.preprocess.tile.tile_noise`): a single return of
        noise hundreds of metres up would set the scale of both views (drawn to equal scales)
        and shrink the tower to a few pixels.
    """
    from towerpipe.io.columns import load_columns
    from towerpipe.io.members import MEMBER_ARRAYS
    from towerpipe.io.tiles import load_tile
    from towerpipe.preprocess.tile import tile_noise

    if not len(towers):
        return {}
    member_keys: set[tuple[str, int]] = set()
    for p in member_files:
        arrays, meta = load_columns(p, list(MEMBER_ARRAYS), "tower-points", "rerun the towers_block job")
        names = list(meta.get("blocks") or [])
        member_keys.update(zip((names[i] for i in arrays["block_id"].tolist()), arrays["point_index"].tolist()))
    boxes = {}
    for r in towers.itertuples(index=False):
        b = r.geometry.bounds
        half = max(radius, 0.5 * max(b[2] - b[0], b[3] - b[1]) + 15.0)
        boxes[r.tower_id] = (r.centroid_x - half, r.centroid_y - half, r.centroid_x + half, r.centroid_y + half)
    parts: dict[str, list[dict[str, np.ndarray]]] = {t: [] for t in boxes}
    seen: dict[str, set[tuple[int, int]]] = {t: set() for t in boxes}
    for path in tile_files:
        tile = load_tile(path, ["x", "y", "z", "hag", "classification", "block_id", "point_index"])
        names = list(tile.meta.get("blocks") or [])
        x, y = tile.arrays["x"], tile.arrays["y"]
        signal = ~tile_noise(tile)
        for tid, (x0, y0, x1, y1) in boxes.items():
            sel = np.flatnonzero((x >= x0) & (x < x1) & (y >= y0) & (y < y1) & signal)
            if not sel.size:
                continue
            bid, pidx = tile.arrays["block_id"][sel], tile.arrays["point_index"][sel]
            # a buffer point is in several tiles: keep each (block, point) once
            keys = list(zip((names[i] for i in bid.tolist()), pidx.tolist()))
            fresh = np.array([k not in seen[tid] for k in keys], dtype=bool)
            seen[tid].update(keys)
            sel = sel[fresh]
            parts[tid].append(
                {
                    "x": x[sel],
                    "y": y[sel],
                    "z": tile.arrays["z"][sel],
                    "tower": np.array([k in member_keys for k, f in zip(keys, fresh) if f], dtype=bool),
                }
            )
    out = {}
    for tid, ps in parts.items():
        if ps:
            out[tid] = {k: np.concatenate([p[k] for p in ps]) for k in ("x", "y", "z", "tower")}
    return out
