"""Clustering predicted tower points into towers: the points of several prediction files
above a threshold (:func:`gather_points`) and their labels by tower (:func:`cluster_towers`).

:func:`towerpipe.towers.extract.extract_towers` applies the tower rules to these clusters;
:func:`towerpipe.towers.matching.towers_from_labels` clusters labelled points the same way.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import shapely
from scipy.spatial import cKDTree

from towerpipe.errors import InputError
from towerpipe.towers.graph import components, nearest_seed
from towerpipe.towers.hull import plan_hull
from towerpipe.towers.masts import split_masts

_PRED_NAMES = ("block_id", "point_index", "x", "y", "z", "hag", "prob")


# --------------------------------------------------------------------------- inputs
def _as_pred(item: Any) -> tuple[Mapping[str, np.ndarray], Mapping[str, Any]]:
    """(arrays, meta) of a prediction path, ``PredFile``, or ``(arrays, meta)`` pair
    (a pair without ``prob_single`` is one view)."""
    from towerpipe.io.predictions import load_pred, one_view_default

    if isinstance(item, (str, os.PathLike)):
        item = load_pred(item)
    if hasattr(item, "arrays") and hasattr(item, "meta"):
        return item.arrays, item.meta
    if isinstance(item, tuple) and len(item) == 2:
        return one_view_default(item[0]), item[1]
    raise TypeError(f"expected a prediction file path, PredFile or (arrays, meta) pair, got {type(item).__name__}")


def gather_points(preds: Sequence[Any], threshold: float) -> dict[str, np.ndarray]:
    """Concatenate the points with ``prob_single >= threshold`` of several prediction files.

    Parameters
    ----------
    preds
        Prediction file paths, :class:`towerpipe.io.predictions.PredFile` objects or
        ``(arrays, meta)`` pairs; ``meta["blocks"]`` names the ``block_id`` values.
        Arrays without ``prob_single`` are one view (``prob`` is used for it).
    threshold
        Minimum single-view tower probability.

    Returns
    -------
    dict
        ``x, y, z`` (float64), ``hag, prob, prob_single`` (float32), ``point_index`` (int64) and
        ``block`` (block names, object array). A point given twice (same block and
        ``point_index``) is kept once.
    """
    cols = ("x", "y", "z", "hag", "prob", "prob_single", "point_index")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in (*cols, "block")}
    for item in preds:
        arrays, meta = _as_pred(item)
        missing = [k for k in _PRED_NAMES if k not in arrays]
        if missing:
            raise InputError(str(meta.get("tile", "<pred>")), f"prediction arrays lack {missing}")
        sel = np.asarray(arrays["prob_single"]) >= threshold
        names = list(meta.get("blocks") or [meta.get("block", "")])
        bid = np.asarray(arrays["block_id"])[sel]
        if bid.size and (bid.min() < 0 or bid.max() >= len(names)):
            raise InputError(str(meta.get("tile", "<pred>")), "block_id outside meta['blocks']")
        parts["block"].append(np.asarray(names, dtype=object)[bid] if bid.size else np.empty(0, dtype=object))
        for k in cols:
            parts[k].append(np.asarray(arrays[k])[sel])
    dtypes = {
        "x": "f8",
        "y": "f8",
        "z": "f8",
        "hag": "f4",
        "prob": "f4",
        "prob_single": "f4",
        "point_index": "i8",
        "block": object,
    }
    out = {k: (np.concatenate(v).astype(dtypes[k]) if v else np.empty(0, dtype=dtypes[k])) for k, v in parts.items()}
    if len(out["x"]):
        # deterministic order and de-duplication: sort by (block, point_index)
        _, bcode = np.unique(out["block"].astype(str), return_inverse=True)
        order = np.lexsort((out["point_index"], bcode))
        key = np.stack([bcode[order], out["point_index"][order]], axis=1)
        keep = np.ones(len(order), dtype=bool)
        keep[1:] = np.any(key[1:] != key[:-1], axis=1)
        out = {k: v[order[keep]] for k, v in out.items()}
    return out


# --------------------------------------------------------------------------- clustering
def _link(xyz: np.ndarray, linkage: float) -> np.ndarray:
    """Component labels of points closer than ``linkage`` (3-D)."""
    if len(xyz) == 0:
        return np.empty(0, dtype=np.int64)
    pairs = cKDTree(xyz).query_pairs(linkage, output_type="ndarray")
    return components(len(xyz), pairs)


def _split_wide(
    xyz: np.ndarray,
    hag: np.ndarray,
    linkage: float,
    reach: float = 10.0,
    cell: float = 1.5,
    min_column: float = 3.0,
    min_count: int = 4,
) -> np.ndarray:
    """Split a too-wide component into towers; return labels (-1 = dropped).

    Towers are vertical structures; falsely predicted wires are thin and nearly
    horizontal. Points in xy cells of size ``cell`` whose HAG spans at least
    ``min_column`` metres with at least ``min_count`` points are *column* points;
    the column points are re-linked, and every other point joins the column
    cluster it is nearest to along the linkage graph when that path is at most
    ``reach`` metres long (crossarms), or is dropped (mid-span wires).
    """
    ij = np.floor(xyz[:, :2] / cell).astype(np.int64)
    _, cell_id = np.unique(ij, axis=0, return_inverse=True)
    cell_id = cell_id.ravel()
    ncell = cell_id.max() + 1
    hmax = np.full(ncell, -np.inf)
    hmin = np.full(ncell, np.inf)
    np.maximum.at(hmax, cell_id, hag)
    np.minimum.at(hmin, cell_id, hag)
    count = np.bincount(cell_id, minlength=ncell)
    is_col = (((hmax - hmin) >= min_column) & (count >= min_count))[cell_id]
    labels = np.full(len(xyz), -1, dtype=np.int64)
    if not is_col.any():
        return labels
    col_idx = np.flatnonzero(is_col)
    return nearest_seed(xyz, col_idx, _link(xyz[col_idx], linkage), linkage, limit=reach)


def _footprint(xy: np.ndarray, min_width: float) -> shapely.Polygon:
    """xy convex hull (oriented rectangle for < 5 points), buffered when degenerate."""
    geom = shapely.oriented_envelope(shapely.multipoints(xy)) if len(xy) < 5 else plan_hull(xy)
    if not isinstance(geom, shapely.Polygon) or geom.area < min_width * min_width:
        geom = shapely.convex_hull(shapely.buffer(geom, min_width / 2.0, quad_segs=4))
    return geom


def cluster_towers(
    xyz: np.ndarray,
    hag: np.ndarray,
    *,
    linkage: float,
    merge_gap: float = 1.0,
    max_extent: float = 25.0,
    reach: float = 10.0,
    mast_prominence: float = 0.0,
    min_points: int,
    min_height: float,
) -> np.ndarray:
    """Label points by tower.

    Parameters
    ----------
    xyz
        (n, 3) float64 coordinates of tower points.
    hag
        (n,) height above ground.
    linkage
        Points closer than this (m, 3-D) belong to the same tower.
    merge_gap
        Clusters whose xy footprints are within this distance (m) are merged.
    max_extent
        A cluster whose xy bounding box is wider than this (m) is split into its
        vertical columns (towers are at most ~20 m wide).
    reach
        When splitting, points further than this (m, along linked points) from
        a vertical column are dropped (mid-span wires).
    min_points, min_height
        Towers with fewer points or a lower max HAG (m) are dropped.

    Returns
    -------
    numpy.ndarray
        (n,) int64 labels ``0..k-1`` ordered by (x, y) of the first point of each
        tower in sorted input order, ``-1`` for points of no tower. Deterministic
        for a given set of points.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    hag = np.asarray(hag, dtype=np.float64)
    n = len(xyz)
    if n == 0:
        return np.empty(0, dtype=np.int64)
    labels = _link(xyz, linkage)
    # split clusters that are too wide to be a single tower
    nlab = labels.max() + 1
    mins = np.full((nlab, 2), np.inf)
    maxs = np.full((nlab, 2), -np.inf)
    np.minimum.at(mins, labels, xyz[:, :2])
    np.maximum.at(maxs, labels, xyz[:, :2])
    wide = np.flatnonzero(np.max(maxs - mins, axis=1) > max_extent)
    if len(wide):
        nxt = nlab
        for lab in wide:
            idx = np.flatnonzero(labels == lab)
            sub = _split_wide(xyz[idx], hag[idx], linkage, reach)
            labels[idx] = np.where(sub >= 0, sub + nxt, -1)
            nxt += sub.max() + 1 if (sub >= 0).any() else 0
    # merge clusters with near footprints
    valid = labels >= 0
    uniq, inv = np.unique(labels[valid], return_inverse=True)
    labels[valid] = inv
    k = len(uniq)
    if k > 1 and merge_gap > 0:
        order = np.argsort(labels[valid], kind="stable")
        vidx = np.flatnonzero(valid)[order]
        splits = np.flatnonzero(np.diff(labels[vidx])) + 1
        hulls = [plan_hull(xyz[g, :2]) for g in np.split(vidx, splits)]
        tree = shapely.STRtree(hulls)
        a, b = tree.query(hulls, predicate="dwithin", distance=merge_gap)
        merged = components(k, np.stack([a, b], axis=1))
        labels[valid] = merged[labels[valid]]
    # split clusters standing on the masts of two towers (crossarms linked, plans touching)
    if mast_prominence > 0 and valid.any():
        nxt = labels.max() + 1
        for lab in np.unique(labels[valid]):
            idx = np.flatnonzero(labels == lab)
            sub = split_masts(xyz[idx], hag[idx], linkage=linkage, prominence=mast_prominence, min_points=min_points)
            if sub.max() > 0:
                labels[idx] = np.where(sub == 0, lab, sub - 1 + nxt)
                nxt += int(sub.max())
    # filters
    valid = labels >= 0
    if valid.any():
        k = labels[valid].max() + 1
        cnt = np.bincount(labels[valid], minlength=k)
        hmax = np.full(k, -np.inf)
        np.maximum.at(hmax, labels[valid], hag[valid])
        good = (cnt >= min_points) & (hmax >= min_height)
        labels[valid & ~good[np.where(valid, labels, 0)]] = -1
    # deterministic relabelling: by smallest (x, y) point of each tower
    valid = labels >= 0
    if not valid.any():
        return labels
    vidx = np.flatnonzero(valid)
    order = vidx[np.lexsort((xyz[vidx, 2], xyz[vidx, 1], xyz[vidx, 0]))]
    _, first = np.unique(labels[order], return_index=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    uniq, inv = np.unique(labels[valid], return_inverse=True)
    labels[valid] = rank[inv]
    return labels
