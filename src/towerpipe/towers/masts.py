"""Two towers in one cluster: the masts a cluster of tower points stands on, and its split into
one cluster per tower (:func:`split_masts`, ``towers.mast_prominence``).

Two towers a few metres apart (a double line, a line crossing another, a branch tower beside a
line tower) make one cluster when their crossarms come within ``towers.linkage`` of each other
or their plans touch (:func:`towerpipe.towers.cluster.cluster_towers`), and one tower is then
reported for two, its outline spanning both. What tells them apart is how a tower stands:

1. **Masts.** Between a tenth and half of the cluster's height, below the crossarms, each
   tower is a body of its own: the points of that band, linked in plan at ``linkage``, make one
   group per tower (a group needs :data:`MIN_BODY_POINTS` points spanning
   :data:`MIN_BODY_SPAN_M` m of height: a shrub's top or a stray point is no mast).
2. **A top each.** A portal's two columns and an H-frame's two poles are masts too, but one
   beam joins them at their tops. Over a height raster of the cluster (the highest point of each
   :data:`CELL_M` m cell), the saddle between two masts is the highest level at which their tops
   are joined by cells at or above it. Two masts are two towers when the lower of the two tops stands at least
   ``prominence`` m, and :data:`PROMINENCE_SHARE` of its height, over that saddle: the poles of
   an H-frame stand 1-1.8 m over its beam, a portal's beam is its top, two towers' crossarms hang
   well below their tops.

Each point joins the mast nearest along the cluster's linkage graph (a crossarm the body it
hangs from), and a mast's top is the highest of its points. Masts whose tops are not that far
apart, or stand closer than :data:`MIN_TOP_GAP_M` (a lattice's legs converge to one top), are one
tower. A split is made only when every tower of it stands as a tower: ``min_points`` points, a
foot on the ground (:data:`GROUND_SHARE`: not a crown painted beside a tower) and its top over
one of its masts (:data:`TOP_OVER_MAST_M`: not one tower's two earth-wire peaks); otherwise the
cluster stays whole, as the tower rules have always judged it.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from towerpipe.towers.graph import components, nearest_seed

#: The band of a cluster's height (shares of its highest point) in which its masts stand apart:
#: above shrubs and a foot's clutter, below the crossarms.
BAND = (0.1, 0.5)
#: The lowest point of the band, whatever the cluster's height (m).
BAND_FLOOR_M = 1.0
#: A mast has at least this many points in the band ...
MIN_BODY_POINTS = 5
#: ... spanning at least this much of its height (m).
MIN_BODY_SPAN_M = 3.0
#: The cell of the height raster the tops and saddles are read from (m).
CELL_M = 1.0
#: Besides ``prominence`` m, the lower top must stand this share of its height over the saddle.
PROMINENCE_SHARE = 0.1
#: Masts whose tops stand closer than this (m, plan) are one tower: a lattice's legs converge to
#: one top a few metres across, the tops of two towers stand a span of crossarms apart.
MIN_TOP_GAP_M = 5.0
#: A tower of a split has its top within this distance (m, plan) of the centre of one of its
#: masts: two towers' tops stand over their bodies, while the two earth-wire peaks of one
#: tower stand out at the ends of its top crossarm, over no leg.
TOP_OVER_MAST_M = 3.0
#: A tower of a split reaches down to this share of its height (or 1 m, :data:`BAND_FLOOR_M`):
#: it stands on the ground, where a crown painted with a tower hangs above it.
GROUND_SHARE = 0.1

_EIGHT = np.ones((3, 3), bool)


def mast_bodies(xyz: np.ndarray, hag: np.ndarray, linkage: float) -> list[np.ndarray]:
    """The masts a cluster stands on: indices of its band points (:data:`BAND`), one array a mast.

    Parameters
    ----------
    xyz
        (n, 3) coordinates of the cluster's points.
    hag
        (n,) their heights above ground.
    linkage
        Band points closer than this in plan (m) belong to one mast.
    """
    top = float(hag.max()) if len(hag) else 0.0
    band = np.flatnonzero((hag >= max(BAND_FLOOR_M, BAND[0] * top)) & (hag <= BAND[1] * top))
    if len(band) < 2 * MIN_BODY_POINTS:
        return []
    pairs = cKDTree(xyz[band, :2]).query_pairs(linkage, output_type="ndarray")
    lab = components(len(band), pairs)
    masts = []
    for k in range(int(lab.max()) + 1):
        m = band[lab == k]
        if len(m) >= MIN_BODY_POINTS and np.ptp(hag[m]) >= MIN_BODY_SPAN_M:
            masts.append(m)
    return masts


def height_raster(xyz: np.ndarray, hag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The highest height above ground in each :data:`CELL_M` m cell of a cluster's plan (``-inf``:
    empty; cells from the cluster's lowest x and y) and each point's cell, (n, 2) int64."""
    ij = np.floor((xyz[:, :2] - xyz[:, :2].min(axis=0)) / CELL_M).astype(np.int64)
    raster = np.full(tuple(ij.max(axis=0) + 1), -np.inf)
    np.maximum.at(raster, (ij[:, 0], ij[:, 1]), hag)
    return raster, ij


def saddle(raster: np.ndarray, a: tuple[int, int], b: tuple[int, int]) -> float:
    """The highest level at which cells ``a`` and ``b`` of ``raster`` (NaN: empty) are joined by
    8-connected cells at or above it (0 when they never are)."""
    filled = np.isfinite(raster)
    lab = ndimage.label(filled, _EIGHT)[0]
    if lab[a] != lab[b]:
        return 0.0
    levels = np.unique(raster[filled])  # ascending: joined at levels[0], not above min(a, b)
    lo, hi = 0, int(np.searchsorted(levels, min(raster[a], raster[b]), side="right")) - 1
    while lo < hi:  # the highest level index at which a and b are joined
        mid = (lo + hi + 1) // 2
        lab = ndimage.label(filled & (raster >= levels[mid]), _EIGHT)[0]
        if lab[a] == lab[b]:
            lo = mid
        else:
            hi = mid - 1
    return float(levels[lo])


def _nearest_mast(xyz: np.ndarray, masts: list[np.ndarray], linkage: float) -> np.ndarray:
    """For each point, the mast nearest along the graph of points closer than ``linkage`` (in
    3-D where no path reaches one)."""
    seeds = np.concatenate(masts)
    seed_mast = np.concatenate([np.full(len(m), k) for k, m in enumerate(masts)])
    return nearest_seed(xyz, seeds, seed_mast, linkage, everywhere=True)


def split_masts(
    xyz: np.ndarray, hag: np.ndarray, *, linkage: float, prominence: float, min_points: int = 1
) -> np.ndarray:
    """Split a cluster standing on the masts of several towers into one cluster per tower.

    Parameters
    ----------
    xyz
        (n, 3) float64 coordinates of the cluster's points.
    hag
        (n,) their heights above ground.
    linkage
        The clustering's linkage (m): masts are linked at it in plan, and the points join a
        mast along the graph of points closer than it.
    prominence
        How far (m) the lower of two towers' tops stands over the saddle between them at least
        (``towers.mast_prominence``; 0: never split).
    min_points
        Each tower of a split holds at least this many points (``towers.min_points``).

    Returns
    -------
    numpy.ndarray
        (n,) int64 labels ``0..k-1``, one per tower (all 0 for one tower). Each point joins the
        mast nearest along the linkage graph (a crossarm the body it hangs from); a mast's top is
        its highest point, and masts whose lower top stands less than ``prominence`` m (and
        :data:`PROMINENCE_SHARE` of its height) over the saddle between them are one tower.
        The cluster stays whole unless every tower of the split holds ``min_points`` points,
        reaches the ground (:data:`GROUND_SHARE`) and has its top over one of its masts
        (:data:`TOP_OVER_MAST_M`).
    """
    labels = np.zeros(len(xyz), np.int64)
    masts = mast_bodies(xyz, hag, linkage) if prominence > 0 and len(xyz) else []
    if len(masts) < 2:
        return labels
    owner = _nearest_mast(xyz, masts, linkage)
    raster, ij = height_raster(xyz, hag)
    raster[np.isneginf(raster)] = np.nan
    tops = []
    for k in range(len(masts)):
        own = np.flatnonzero(owner == k)
        top = own[int(np.argmax(hag[own]))]
        tops.append((float(hag[top]), (int(ij[top, 0]), int(ij[top, 1]))))
    same = []
    for i in range(len(masts)):
        for j in range(i + 1, len(masts)):
            low = min(tops[i][0], tops[j][0])
            gap = CELL_M * float(np.hypot(*np.subtract(tops[i][1], tops[j][1])))
            if gap < MIN_TOP_GAP_M or low - saddle(raster, tops[i][1], tops[j][1]) < max(
                prominence, PROMINENCE_SHARE * low
            ):
                same.append((i, j))
    tower = components(len(masts), np.array(same, np.int64).reshape(-1, 2))
    if tower.max() == 0:
        return labels
    centres = np.array([np.median(xyz[m, :2], axis=0) for m in masts])
    for k in range(int(tower.max()) + 1):
        own = np.flatnonzero(tower[owner] == k)
        top = own[int(np.argmax(hag[own]))]
        over = np.hypot(*(centres[tower == k] - xyz[top, :2]).T).min()
        floor = max(BAND_FLOOR_M, GROUND_SHARE * float(hag[top]))
        if len(own) < min_points or hag[own].min() > floor or over > TOP_OVER_MAST_M:
            return labels
    return np.unique(tower[owner], return_inverse=True)[1].astype(np.int64)
