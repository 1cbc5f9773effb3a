"""Towers as objects: cluster predicted tower points into one record per tower.

The segmenter gives every point a tower probability, from the window as it is
(``prob_single``) and averaged over several views of it (``prob``, see
:func:`towerpipe.inference.infer.segment_views`). :func:`extract_towers` turns the points of one
block *and its neighbours* with ``prob_single >= threshold`` into towers (a tower the
segmenter is unsure of in some views is still found), and a tower's points are those of
its cluster with ``prob >= point_threshold`` (a crown painted in one view is left out):

1. connected components of a 3-D ``cKDTree`` graph (points closer than ``linkage``);
2. a component wider than ``max_extent`` (a chain of falsely predicted wire points
   linking towers) is split into its vertical columns (see :func:`_split_wide`);
3. components whose xy footprints are within ``merge_gap`` of each other are merged
   (a tower whose crossarms were separated from its body);
4. towers with fewer than ``min_points`` points or lower than ``min_height`` (max HAG)
   are dropped (the paper's towers are >= 10 m high and >= 20 points), and so are
   towers without a confident core: fewer than 10 % of their points at or above
   ``min_core_prob`` (a tower's body comes out of the segmenter near 1; the false
   clusters in trees beside a line hover just above the point threshold);
5. only towers whose footprint centroid lies in the block's half-open bounds
   ``[xmin, xmax) x [ymin, ymax)`` are kept, so a tower across a tile or block edge
   is built from all its points and reported by exactly one block;
6. clusters floating above the ground (lowest point above ``max_base_ratio`` of
   their height) are dropped: pieces of conductor or crossarm;
7. with a ``context`` (the tile points around a tower), each tower gets its
   conductor support (:func:`towerpipe.towers.wires.wire_support`: the share of the 80-160 m
   ring reached by a wire pointing at its base), and towers at least ``wire_min_height``
   high with a support below ``min_wire_support`` are dropped: a transmission tower
   carries conductors to the next tower, a crane or a mast does not.

A tower's id is the zone registry's when it matches a registered tower, else made from
the centroid where it is first seen (:mod:`towerpipe.towers.registry`): it depends on the
tower's points and the registry, never on file or processing order nor on the zone's
name. :func:`match_towers` compares towers with ground truth (synthetic sidecar or
towers built from class-15 labels).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime, timezone
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from towerpipe.errors import InputError
from towerpipe.products.fields import DATETIME, GEOMETRY_GRID, Field, conform, dtypes, empty_frame, join_values
from towerpipe.towers.registry import REVIEW_STATUSES, assign_ids

#: Fields of a tower record (besides the footprint geometry), in order: the GeoPackage
#: layers ``towers`` and ``tower_points`` use exactly these.
TOWER_FIELDS: dict[str, Field] = {
    "tower_id": Field("int64", "Tower id",
                      "Stable id (docs/products.md): the first-seen footprint centroid on a 1 m grid, "
                      "(x mod 9e7) * 1e8 + (y mod 1e8); kept from run to run by the zone's registry. The "
                      "TowerpipeTowerId of the tower's points in the classified blocks"),
    "zone": Field("str", "Zone", "Zone name"),
    "block": Field("str", "Owning block", "Block holding the footprint centroid: the block that reports the tower"),
    "blocks": Field("str", "Blocks touched", "Blocks the tower's points come from, ';'-separated"),
    "centroid_x": Field("float64", "Centroid X (m)", "Footprint centroid, CRS units (m)", 2),
    "centroid_y": Field("float64", "Centroid Y (m)", "Footprint centroid, CRS units (m)", 2),
    "height_m": Field("float64", "Height (m)", "Height of the tower: top_z - base_z (m)", 2),
    "base_z": Field("float64", "Base elevation (m)",
                    "Ground elevation at the tower: median of z - HAG over its points (m)", 2),
    "top_z": Field("float64", "Top elevation (m)", "Elevation of the tower's highest point (m)", 2),
    "footprint_area_m2": Field("float64", "Footprint area (m²)", "Area of the xy footprint (m²)", 2),
    "footprint_width_m": Field("float64", "Footprint width (m)", "Short side of the footprint's minimum "
                                                                  "rotated rectangle (m)", 2),
    "footprint_length_m": Field("float64", "Footprint length (m)", "Long side of the footprint's minimum "
                                                                    "rotated rectangle (m)", 2),
    "edge_distance_m": Field("float64", "Distance to block edge (m)",
                             "Distance from the centroid to the nearest edge of the owning block (m)", 2),
    "n_points": Field("int64", "Points", "Points of the tower: those classified 15 in the classified blocks"),
    "prob_mean": Field("float64", "Mean probability",
                       "Mean single-view tower probability (0-1) of the points of its cluster", 3),
    "prob_max": Field("float64", "Max probability",
                      "Highest single-view tower probability (0-1) of the points of its cluster", 3),
    "wire_support": Field("float64", "Conductor support (0-1)",
                          "Share (0-1) of the 80-160 m ring around the base reached by a conductor pointing at "
                          "it; NULL when unknown (no data around)", 3),
    "line_id": Field("Int64", "Line id", "Line of the tower (layer lines): the smallest tower_id on the line; "
                                         "NULL when the tower is linked to no other (set in the zone's file)"),
    "line_seq": Field("Int64", "Position on the line", "1, 2, … along the line (layer lines); NULL off a line"),
    "line_chainage_m": Field("float64", "Chainage (m)",
                             "Distance along the line from its first tower, through the towers (m)", 2),
    "bearing_deg": Field("float64", "Line bearing (°)",
                         "Azimuth of the line at the tower, degrees clockwise from grid north, toward increasing "
                         "line_seq (at an angle tower the bisector of its two spans); the crossarm is "
                         "perpendicular. For a tower on no line, the axis of its conductors (0-180); NULL "
                         "when no conductor was found", 1),
    "deflection_deg": Field("float64", "Line deflection (°)",
                            "Angle the line turns at the tower (0 = straight through; angle towers); NULL at the "
                            "ends of a line", 1),
    "review_status": Field("str", "Review status", "Analyst review: unreviewed (default), confirmed or "
                                                   "rejected; kept from run to run by the registry",
                           enum=REVIEW_STATUSES),
    "first_seen": Field(DATETIME, "First seen (UTC)", "When the tower was first found (when its id was made)"),
    "source_files": Field("str", "Source files", "Absolute paths of the input files of its blocks, ';'-separated"),
    "model_name": Field("str", "Model", "Model that predicted the tower points"),
    "model_version": Field("str", "Model version", "Version of that model"),
    "processed_at": Field(DATETIME, "Processed at (UTC)", "Time of the towers step"),
}
#: Column name → dtype of :data:`TOWER_FIELDS`.
TOWER_COLUMNS: dict[str, str] = dtypes(TOWER_FIELDS)

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


def gather_points(preds: Sequence[Any], threshold: float = 0.5) -> dict[str, np.ndarray]:
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
    dtypes = {"x": "f8", "y": "f8", "z": "f8", "hag": "f4", "prob": "f4", "prob_single": "f4", "point_index": "i8",
              "block": object}
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
def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component labels of ``n`` nodes joined by ``pairs`` (k, 2)."""
    if n == 0:
        return np.empty(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _link(xyz: np.ndarray, linkage: float) -> np.ndarray:
    """Component labels of points closer than ``linkage`` (3-D)."""
    if len(xyz) == 0:
        return np.empty(0, dtype=np.int64)
    pairs = cKDTree(xyz).query_pairs(linkage, output_type="ndarray")
    return _components(len(xyz), pairs)


def _split_wide(xyz: np.ndarray, hag: np.ndarray, linkage: float, reach: float = 10.0, cell: float = 1.5,
                min_column: float = 3.0, min_count: int = 4) -> np.ndarray:
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
    labels[col_idx] = _link(xyz[col_idx], linkage)
    pairs = cKDTree(xyz).query_pairs(linkage, output_type="ndarray")
    w = np.linalg.norm(xyz[pairs[:, 0]] - xyz[pairs[:, 1]], axis=1) + 1e-9
    graph = coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(len(xyz), len(xyz))).tocsr()
    dist, _, source = dijkstra(graph, directed=False, indices=col_idx, min_only=True, limit=reach,
                               return_predecessors=True)
    ok = np.isfinite(dist) & (source >= 0)
    labels[ok] = labels[source[ok]]
    return labels


def _footprint(xy: np.ndarray, min_width: float) -> shapely.Polygon:
    """xy convex hull (oriented rectangle for < 5 points), buffered when degenerate."""
    mp = shapely.multipoints(xy)
    geom = shapely.oriented_envelope(mp) if len(xy) < 5 else shapely.convex_hull(mp)
    if not isinstance(geom, shapely.Polygon) or geom.area < min_width * min_width:
        geom = shapely.convex_hull(shapely.buffer(geom, min_width / 2.0, quad_segs=4))
    return geom


def cluster_towers(xyz: np.ndarray, hag: np.ndarray, *, linkage: float = 2.5, merge_gap: float = 1.0,
                   max_extent: float = 25.0, reach: float = 10.0, min_points: int = 20,
                   min_height: float = 10.0) -> np.ndarray:
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
        hulls = [shapely.convex_hull(shapely.multipoints(xyz[g, :2])) for g in np.split(vidx, splits)]
        tree = shapely.STRtree(hulls)
        a, b = tree.query(hulls, predicate="dwithin", distance=merge_gap)
        merged = _components(k, np.stack([a, b], axis=1))
        labels[valid] = merged[labels[valid]]
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


# --------------------------------------------------------------------------- records
def empty_towers(crs: Any = None) -> gpd.GeoDataFrame:
    """An empty tower table with the full schema (:data:`TOWER_FIELDS` + Polygon geometry)."""
    return empty_frame(TOWER_FIELDS, crs)


def _in_bounds(x: np.ndarray, y: np.ndarray, bounds: Sequence[float]) -> np.ndarray:
    xmin, ymin, xmax, ymax = bounds
    return (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)


def extract_towers(
    preds: Sequence[Any],
    block_name: str,
    block_bounds: Sequence[float],
    *,
    zone: str,
    threshold: float = 0.5,
    linkage: float = 2.5,
    merge_gap: float = 1.0,
    max_extent: float = 25.0,
    min_points: int = 20,
    min_height: float = 10.0,
    min_width: float = 1.0,
    min_core_prob: float = 0.0,
    model_meta: Mapping[str, Any] | None = None,
    source_files: Mapping[str, str] | None = None,
    crs: Any = None,
    processed_at: str | None = None,
    neighbours: list[dict[str, Any]] | None = None,
    context: Callable[[float, float], tuple[Mapping[str, np.ndarray], Sequence[float]] | None] | None = None,
    min_wire_support: float = 0.0,
    wire_min_height: float = 20.0,
    max_base_ratio: float = 1.0,
    point_threshold: float | None = None,
    members: dict[int, tuple[np.ndarray, np.ndarray]] | None = None,
    registry: gpd.GeoDataFrame | None = None,
) -> gpd.GeoDataFrame:
    """Towers owned by one block, built from the predictions of the block and its neighbours.

    Parameters
    ----------
    preds
        Prediction files (paths, ``PredFile`` objects or ``(arrays, meta)`` pairs)
        of the block **and its neighbours**, so that a tower across a block edge
        is complete.
    block_name
        The block whose towers are returned (recorded in ``block``).
    block_bounds
        ``(xmin, ymin, xmax, ymax)`` of the block; a tower belongs to the block
        when its footprint centroid is in ``[xmin, xmax) x [ymin, ymax)``.
    zone
        Zone name (recorded in ``zone``; not part of the id).
    threshold
        Minimum single-view tower probability (``prob_single``) of a point.
    linkage, merge_gap, max_extent, min_points, min_height
        Clustering parameters, see :func:`cluster_towers`.
    min_width
        Footprints thinner than this (m) are buffered to this width.
    min_core_prob
        A tower whose 90th percentile of single-view point probabilities is below this
        is dropped (0 keeps every cluster); the LAS keeps its points' probabilities.
        ``prob_mean`` and ``prob_max`` of a tower are of the same probabilities.
    model_meta
        ``{"name": ..., "version": ...}``; default: ``meta["model"]`` of the first
        prediction file.
    source_files
        Block name → input point-cloud path; a tower lists the files of the blocks
        its points come from (made absolute).
    crs
        CRS of the result (WKT, EPSG string, ``pyproj.CRS``); default:
        ``meta["crs_wkt"]`` of the first prediction file.
    processed_at
        ISO timestamp recorded in every record (default: now, UTC).
    neighbours
        When a list is given, each tower that has points in this block but is owned by
        a neighbour (its centroid lies there) is appended to it as ``{"tower_id",
        "footprint_wkt", "blocks"}``; the block's QA uses them so that a labelled edge
        tower reported by the neighbour is not counted as missed.
    context
        ``context(cx, cy)`` gives the points around a tower centre, ``({"x", "y", "z",
        "hag"} arrays, covered extent)``, or ``None``; then ``wire_support`` is
        computed (:func:`towerpipe.towers.wires.wire_support`). Without it the column is NaN.
    min_wire_support, wire_min_height
        Towers with a max HAG of at least ``wire_min_height`` (m) and a wire support
        below ``min_wire_support`` are dropped (0 keeps every tower; an unknown, NaN,
        support never drops one).
    max_base_ratio
        Towers whose lowest point is higher than this share of their height above
        ground are dropped (1 keeps all): a tower stands on the ground, a floating
        cluster is a piece of conductor or crossarm.
    point_threshold
        The points of a tower are its cluster's points whose view-averaged probability
        (``prob``) is at or above this (``n_points`` and ``members``); ``None``: all of
        them. A tower with fewer than ``min_points`` such points is dropped. This trims the uncertain edge of each tower (crowns next to it) without
        splitting off the pieces of conductor that a higher clustering threshold leaves
        as false towers, and without losing a tower the segmenter is unsure of.
    members
        When a dict is given, ``members[tower_id] = (block names, point indices)`` of
        the points of every accepted tower with points in this block, owned or not (a
        neighbour's tower across the edge passes the same rules on the same points and
        tiles there), for the classified block: its class-15 points and their tower id.
    registry
        The zone's tower registry (:func:`towerpipe.towers.registry.read_registry`): a tower
        matching a registered one keeps its id, review status and ``first_seen``; others
        get a new id from their location (:func:`towerpipe.towers.registry.assign_ids`). Ids are
        assigned over every accepted tower the job sees (its own and those of its
        neighbours it reaches into), so both jobs give a tower across an edge one id.

    Returns
    -------
    geopandas.GeoDataFrame
        One row per tower, columns :data:`TOWER_COLUMNS` and the footprint
        Polygon, sorted by ``tower_id``. Empty (full schema) when there is none.
    """
    preds = [_as_pred(p) for p in preds]
    metas = [m for _, m in preds]
    if crs is None:
        crs = next((m["crs_wkt"] for m in metas if m.get("crs_wkt")), None)
    if model_meta is None:
        model_meta = next((m["model"] for m in metas if m.get("model")), {})
    if processed_at is None:
        processed_at = datetime.now(timezone.utc).replace(microsecond=0).isoformat()
    pts = gather_points(preds, threshold)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
    labels = cluster_towers(xyz, pts["hag"], linkage=linkage, merge_gap=merge_gap, max_extent=max_extent,
                            min_points=min_points, min_height=min_height)
    if not (labels >= 0).any():
        return empty_towers(crs)
    sources = dict(source_files or {})
    order = np.argsort(labels, kind="stable")
    order = order[labels[order] >= 0]
    groups = np.split(order, np.flatnonzero(np.diff(labels[order])) + 1)
    xmin, ymin, xmax, ymax = (float(v) for v in block_bounds)
    rows, geoms, accepted = [], [], []
    for g in groups:
        if min_core_prob > 0 and np.quantile(pts["prob_single"][g], 0.9) < min_core_prob:
            continue
        hag = pts["hag"][g].astype(np.float64)
        if hag.min() > max_base_ratio * hag.max():
            continue  # floating: a piece of conductor or crossarm, not a tower standing on the ground
        xy = xyz[g, :2]
        foot = shapely.set_precision(_footprint(xy, min_width), GEOMETRY_GRID)  # as written: 1 cm
        c = foot.centroid
        touched = sorted(set(pts["block"][g].tolist()))
        owned = bool(_in_bounds(np.array([c.x]), np.array([c.y]), block_bounds)[0])
        if not owned and str(block_name) not in touched:
            continue  # a neighbour's tower that does not reach this block
        prob = pts["prob_single"][g].astype(np.float64)
        support = float("nan")
        ctx = context(float(c.x), float(c.y)) if context is not None else None
        if ctx is not None:
            from towerpipe.towers.wires import wire_support

            # measured from the tower's base (median xy of its lowest third): a crane's
            # footprint centroid lies out along its jib, its base is the mast
            low = hag <= hag.min() + (hag.max() - hag.min()) / 3.0
            bx, by = np.median(xy[low], axis=0)
            arr, extent = ctx
            support = wire_support(arr["x"], arr["y"], arr["z"], arr["hag"], float(bx), float(by), extent=extent)
            if hag.max() >= wire_min_height and support < min_wire_support:
                continue
        g_pts = g if point_threshold is None else g[pts["prob"][g] >= point_threshold]
        if len(g_pts) < min_points:
            continue  # what would be reported is too few points for a tower (the paper's 20)
        accepted.append((g, g_pts, foot, touched, owned, support, hag, prob))
    if not accepted:
        return empty_towers(crs)
    ids, first_seen, review = assign_ids([a[2] for a in accepted], registry)
    stamp = pd.Timestamp(processed_at)
    stamp = stamp.tz_localize("UTC") if stamp.tzinfo is None else stamp.tz_convert("UTC")
    for (g, g_pts, foot, touched, owned, support, hag, prob), tid, first, rev in zip(accepted, ids.tolist(),
                                                                                    first_seen, review):
        if members is not None:
            members[tid] = (pts["block"][g_pts], pts["point_index"][g_pts])
        if not owned:
            # reported by the neighbour that holds its centroid (the same rules on the same
            # points and tiles decide there); listed for this block's QA
            if neighbours is not None:
                neighbours.append({"tower_id": tid, "footprint_wkt": foot.wkt, "blocks": join_values(touched)})
            continue
        c = foot.centroid
        rect = shapely.oriented_envelope(foot)
        ring = np.asarray(rect.exterior.coords) if isinstance(rect, shapely.Polygon) else np.zeros((2, 2))
        sides = np.hypot(*np.diff(ring[:3], axis=0).T) if len(ring) >= 3 else np.zeros(2)
        # top and base to the cm, and the height their difference: height_m = top_z - base_z exactly
        top = round(float(xyz[g, 2].max()), 2)
        base = round(float(np.median(xyz[g, 2] - hag)), 2)
        rows.append({
            "tower_id": tid,
            "zone": str(zone),
            "block": str(block_name),
            "blocks": join_values(touched),
            "centroid_x": float(c.x),
            "centroid_y": float(c.y),
            "height_m": round(top - base, 2),
            "base_z": base,
            "top_z": top,
            "footprint_area_m2": float(foot.area),
            "footprint_width_m": float(np.min(sides)),
            "footprint_length_m": float(np.max(sides)),
            "edge_distance_m": float(min(c.x - xmin, xmax - c.x, c.y - ymin, ymax - c.y)),
            "n_points": int(len(g_pts)),
            "prob_mean": float(prob.mean()),
            "prob_max": float(prob.max()),
            "wire_support": support,
            "line_id": None, "line_seq": None, "line_chainage_m": np.nan, "bearing_deg": np.nan,
            "deflection_deg": np.nan,
            "review_status": rev,
            "first_seen": first if first is not None and pd.notna(first) else stamp,
            "source_files": join_values(os.path.abspath(sources[b]) for b in touched if b in sources),
            "model_name": str(model_meta.get("name", "")),
            "model_version": str(model_meta.get("version", "")),
            "processed_at": stamp,
        })
        geoms.append(foot)
    if not rows:
        return empty_towers(crs)
    gdf = gpd.GeoDataFrame(rows, geometry=geoms, crs=crs)
    return conform(gdf.sort_values("tower_id", kind="stable"), TOWER_FIELDS, crs)


# --------------------------------------------------------------------------- tower points
#: Arrays of a tower-points file: the points (in any block) of the accepted towers that have
#: points in one block, ``block_id`` indexing ``meta["blocks"]`` and ``tower`` indexing
#: ``meta["towers"]``.
MEMBER_ARRAYS: dict[str, np.dtype] = {"block_id": np.dtype("i4"), "point_index": np.dtype("i8"),
                                      "tower": np.dtype("i4")}


def save_members(path: str | os.PathLike[str], members: Mapping[int, tuple[np.ndarray, np.ndarray]]) -> None:
    """Write the points of reported towers (``extract_towers(..., members=...)``) atomically.

    ``meta["towers"]`` lists the (integer) tower ids that ``tower`` indexes.
    """
    from towerpipe.io.columns import save_columns

    ids = sorted(int(t) for t in members)
    names = sorted({str(b) for bl, _ in members.values() for b in np.asarray(bl).tolist()})
    code = {b: i for i, b in enumerate(names)}
    parts = {k: [] for k in MEMBER_ARRAYS}
    for t, tid in enumerate(ids):
        bl, idx = members[tid]
        parts["block_id"].append(np.array([code[str(b)] for b in np.asarray(bl).tolist()], dtype=np.int32))
        parts["point_index"].append(np.asarray(idx, dtype=np.int64))
        parts["tower"].append(np.full(len(idx), t, dtype=np.int32))
    arrays = {k: (np.concatenate(v) if v else np.empty(0, d)).astype(d) for (k, d), v in
              zip(MEMBER_ARRAYS.items(), parts.values())}
    save_columns(path, arrays, {"blocks": names, "towers": ids})


def member_ids(paths: Sequence[str | os.PathLike[str]], block: str, n_points: int) -> np.ndarray:
    """``(n_points,)`` uint64: the ``tower_id`` of each point of ``block`` in a reported tower, 0 elsewhere.

    Parameters
    ----------
    paths
        Tower-points files (:func:`save_members`), e.g. the block's own (every accepted
        tower with points in the block, whichever block reports it).
    block
        The block's name.
    n_points
        Points in the block file.
    """
    from towerpipe.io.columns import load_columns, validate_columns

    out = np.zeros(int(n_points), dtype=np.uint64)
    for p in paths:
        arrays, meta = load_columns(p, list(MEMBER_ARRAYS), "tower-points", "rerun the towers_block job")
        validate_columns(arrays, MEMBER_ARRAYS, p, "tower-points", "rerun the towers_block job")
        names = list(meta.get("blocks") or [])
        if block not in names:
            continue
        try:
            ids = np.asarray([int(t) for t in meta.get("towers") or []], dtype=np.uint64)
        except (TypeError, ValueError) as exc:
            raise InputError(p, f"tower ids are not integers ({exc}): the file is from an older version; rerun "
                                "the towers_block job") from exc
        sel = arrays["block_id"] == names.index(block)
        idx, tower = arrays["point_index"][sel], arrays["tower"][sel]
        if len(idx) and (idx.min() < 0 or idx.max() >= n_points):
            raise InputError(p, f"point_index out of range for block {block!r} ({n_points} points); the file is "
                                "stale: rerun the towers_block job")
        if len(tower) and (tower.min() < 0 or tower.max() >= len(ids)):
            raise InputError(p, "tower index outside meta['towers']: rerun the towers_block job")
        out[idx] = ids[tower]
    return out


def member_mask(paths: Sequence[str | os.PathLike[str]], block: str, n_points: int) -> np.ndarray:
    """``(n_points,)`` bool: the points of ``block`` that belong to a reported tower (:func:`member_ids` > 0)."""
    return member_ids(paths, block, n_points) > 0


# --------------------------------------------------------------------------- truth / evaluation
def towers_from_labels(x: np.ndarray, y: np.ndarray, z: np.ndarray, hag: np.ndarray | None, is_tower: np.ndarray,
                       *, linkage: float = 2.5, min_points: int = 1, min_height: float = 0.0,
                       min_width: float = 1.0, crs: Any = None) -> gpd.GeoDataFrame:
    """Truth towers from point labels (e.g. input Classification == 15).

    Clusters the labelled points as :func:`cluster_towers` does (no size filter by
    default) and returns ``tower_id`` (``truth_<k>``), ``n_points``, ``height_m``
    (max HAG, or z range when ``hag`` is None) and the footprint Polygon.
    """
    sel = np.asarray(is_tower, dtype=bool)
    xyz = np.stack([np.asarray(x)[sel], np.asarray(y)[sel], np.asarray(z)[sel]], axis=1).astype(np.float64)
    h = np.asarray(hag)[sel].astype(np.float64) if hag is not None else None
    if h is None:
        h = xyz[:, 2] - (xyz[:, 2].min() if len(xyz) else 0.0)
    labels = cluster_towers(xyz, h, linkage=linkage, merge_gap=1.0, max_extent=np.inf,
                            min_points=min_points, min_height=min_height)
    rows, geoms = [], []
    for k in range(labels.max() + 1 if len(labels) else 0):
        g = np.flatnonzero(labels == k)
        if len(g) == 0:
            continue
        rows.append({"tower_id": f"truth_{k}", "n_points": int(len(g)), "height_m": float(h[g].max())})
        geoms.append(_footprint(xyz[g, :2], min_width))
    if not rows:
        return gpd.GeoDataFrame({"tower_id": [], "n_points": [], "height_m": []},
                                geometry=gpd.GeoSeries([], crs=crs), crs=crs)
    return gpd.GeoDataFrame(rows, geometry=geoms, crs=crs)


def _ids(gdf: gpd.GeoDataFrame) -> list[str]:
    for col in ("tower_id", "id"):
        if col in gdf.columns:
            return [str(v) for v in gdf[col]]
    return [str(i) for i in gdf.index]


def f1_score(precision: float | None, recall: float | None) -> float | None:
    """Harmonic mean of precision and recall; None when either is undefined, 0 when both are 0."""
    if precision is None or recall is None:
        return None
    return 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0


def match_towers(pred: gpd.GeoDataFrame, truth: gpd.GeoDataFrame, max_dist: float = 5.0) -> dict[str, Any]:
    """Match predicted towers to true towers one-to-one.

    A pair is a candidate when the footprints intersect or the footprint centroids
    are within ``max_dist`` metres; candidates are taken greedily by increasing
    centroid distance, each tower used at most once.

    Parameters
    ----------
    pred, truth
        GeoDataFrames with footprint polygons; ids from ``tower_id`` (or ``id``).
    max_dist
        Centroid distance (m) below which towers match even without overlap.

    Returns
    -------
    dict
        ``precision``, ``recall``, ``f1`` (None when undefined: no towers on that
        side), ``tp``, ``fp``, ``fn``, ``matches`` (list of ``{"pred", "truth",
        "distance_m"}``), ``unmatched_pred``, ``unmatched_truth`` (id lists).
    """
    pid, tid = _ids(pred), _ids(truth)
    pg = np.asarray(pred.geometry.values, dtype=object) if len(pred) else np.empty(0, dtype=object)
    tg = np.asarray(truth.geometry.values, dtype=object) if len(truth) else np.empty(0, dtype=object)
    matches: list[dict[str, Any]] = []
    if len(pg) and len(tg):
        pc = shapely.get_coordinates(shapely.centroid(pg))
        tc = shapely.get_coordinates(shapely.centroid(tg))
        dist = np.hypot(pc[:, None, 0] - tc[None, :, 0], pc[:, None, 1] - tc[None, :, 1])
        inter = shapely.intersects(pg[:, None], tg[None, :])
        cand = np.argwhere((dist <= max_dist) | inter)
        cand = cand[np.lexsort((cand[:, 1], cand[:, 0], dist[cand[:, 0], cand[:, 1]]))]
        used_p, used_t = set(), set()
        for i, j in cand:
            if i in used_p or j in used_t:
                continue
            used_p.add(i)
            used_t.add(j)
            matches.append({"pred": pid[i], "truth": tid[j], "distance_m": float(dist[i, j])})
    tp = len(matches)
    fp, fn = len(pid) - tp, len(tid) - tp
    precision = tp / len(pid) if pid else None
    recall = tp / len(tid) if tid else None
    mp = {m["pred"] for m in matches}
    mt = {m["truth"] for m in matches}
    return {
        "precision": precision, "recall": recall, "f1": f1_score(precision, recall), "tp": tp, "fp": fp, "fn": fn,
        "matches": matches,
        "unmatched_pred": [i for i in pid if i not in mp],
        "unmatched_truth": [i for i in tid if i not in mt],
    }
