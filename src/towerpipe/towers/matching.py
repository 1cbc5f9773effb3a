"""Comparing towers: one-to-one matching of towers (:func:`match_towers`), precision / recall /
F1, and truth towers built from point labels (:func:`towers_from_labels`).
"""

from __future__ import annotations

from typing import Any

import geopandas as gpd
import numpy as np
import shapely

from towerpipe.towers.cluster import _footprint, cluster_towers


def towers_from_labels(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    hag: np.ndarray | None,
    is_tower: np.ndarray,
    *,
    linkage: float = 2.5,
    min_points: int = 1,
    min_height: float = 0.0,
    min_width: float = 1.0,
    mast_prominence: float = 0.0,
    crs: Any = None,
) -> gpd.GeoDataFrame:
    """Truth towers from point labels (e.g. input Classification == 15).

    Clusters the labelled points as :func:`towerpipe.towers.cluster.cluster_towers` does (no size filter by
    default; with ``mast_prominence`` two towers whose crossarms touch are two, as ``towers.mast_prominence``)
    and returns ``tower_id`` (``truth_<k>``), ``n_points``, ``height_m``
    (max HAG, or the cluster's z range when ``hag`` is None) and the footprint Polygon.
    """
    sel = np.asarray(is_tower, dtype=bool)
    # indexed, not converted first: a column read a piece at a time gives only the tower points
    xyz = np.stack([np.asarray(a[sel]) for a in (x, y, z)], axis=1).astype(np.float64)
    h = np.asarray(hag[sel]).astype(np.float64) if hag is not None else None
    if h is None:
        h = xyz[:, 2] - (xyz[:, 2].min() if len(xyz) else 0.0)
    labels = cluster_towers(
        xyz,
        h,
        linkage=linkage,
        merge_gap=1.0,
        max_extent=np.inf,
        mast_prominence=mast_prominence,
        min_points=min_points,
        min_height=min_height,
    )
    rows, geoms = [], []
    for k in range(labels.max() + 1 if len(labels) else 0):
        g = np.flatnonzero(labels == k)
        if len(g) == 0:
            continue
        # without heights above ground, a cluster's own z range (not the rise over the zone's lowest tower point)
        height = h[g].max() if hag is not None else np.ptp(xyz[g, 2])
        rows.append({"tower_id": f"truth_{k}", "n_points": int(len(g)), "height_m": float(height)})
        geoms.append(_footprint(xyz[g, :2], min_width))
    if not rows:
        return gpd.GeoDataFrame(
            {"tower_id": [], "n_points": [], "height_m": []}, geometry=gpd.GeoSeries([], crs=crs), crs=crs
        )
    return gpd.GeoDataFrame(rows, geometry=geoms, crs=crs)


def tower_ids(gdf: gpd.GeoDataFrame) -> list[str]:
    """The ids :func:`match_towers` names towers by: ``tower_id`` (or ``id``, or the index), as text."""
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
    pid, tid = tower_ids(pred), tower_ids(truth)
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
        "precision": precision,
        "recall": recall,
        "f1": f1_score(precision, recall),
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "matches": matches,
        "unmatched_pred": [i for i in pid if i not in mp],
        "unmatched_truth": [i for i in tid if i not in mt],
    }
