"""Two towers in one accepted cluster: its prominent peaks, each over a body of its own
(:func:`peak_parts`, ``towers.peak_share``; rule 23 of :mod:`towerpipe.towers.extract`).

:func:`towerpipe.towers.masts.split_masts` parts a cluster whose towers' bodies stand apart below
their crossarms. Where the bodies are linked too, by a crown painted between them or a crossarm
reaching into the other tower, it finds one mast, and the cluster is reported as one tower with
its outline over both. What still tells two towers apart is their tops. Over a height raster of
the cluster (the highest point of each :data:`~towerpipe.towers.masts.CELL_M` m cell):

1. **Peaks.** The cells highest within :data:`~towerpipe.towers.masts.MIN_TOP_GAP_M` m, taken
   from the highest down. A lower peak counts when it stands :data:`LOW_SHARE` of the highest
   peak's height or more (a crown or a shrub at a tower's foot is not a tower beside it), and
   ``prominence`` m and ``share`` of its height over the saddle to every peak kept (one tower's
   earth-wire peaks stand a few metres over its top crossarm, a tower beside another stands over
   the crossarms or crowns linking them by more). An empty cell takes the highest height within
   :data:`FILL_M` m, so that a sparse tower's own peaks stay joined by its crossarm.
2. **A body under each.** The points within :data:`COLUMN_R_M` m (plan) of a lower peak reach down
   to :data:`BODY_SHARE` of its height with no gap over :data:`MAX_GAP_SHARE` of it: a crossarm's
   end over a shrub is not a tower.
3. **Parts.** Each point joins the peak whose column is nearest along the cluster's linkage graph.
   Every part holds ``min_points`` points, reaches down to :data:`BODY_SHARE` of its top, and stands
   :data:`~towerpipe.towers.masts.MIN_TOP_GAP_M` m or more from the others (its
   :func:`~towerpipe.towers.plan.base`: the two halves of one V-shaped tower share a base). While a
   part fails, the lowest peak failing is dropped and the rest parted again.

Only a cluster the tower rules accept is parted, and each part is judged by them again: a crown
cut from a tower falls to the shape check, and a cluster the rules drop (two crowns) is never cut
into pieces one of which they could keep.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from towerpipe.towers.graph import nearest_seed
from towerpipe.towers.masts import BAND_FLOOR_M, CELL_M, MIN_TOP_GAP_M, height_raster, saddle
from towerpipe.towers.plan import base

#: A lower peak stands at least this share of the highest peak's height: a shrub or a crown at a
#: tower's foot is no tower beside it.
LOW_SHARE = 0.4
#: An empty cell of the raster takes the highest height within this distance (m, under
#: ``towers.linkage``): the points of a sparse crossarm, linked in the cluster, stay joined over it.
FILL_M = 2.0
#: The column of points under a peak: within this distance of it in plan (m).
COLUMN_R_M = 3.0
#: A peak's column, and a part, reach down to this share of its height.
BODY_SHARE = 0.5
#: No gap in a peak's column is wider than this share of its height.
MAX_GAP_SHARE = 0.2


def _has_body(hag: np.ndarray, top: float) -> bool:
    """Whether a column's heights ``hag`` reach down to :data:`BODY_SHARE` of ``top`` without a
    gap wider than :data:`MAX_GAP_SHARE` of it."""
    h = np.sort(hag[hag <= top])[::-1]
    down = np.flatnonzero(h <= BODY_SHARE * top)
    if len(down) == 0:
        return False
    steps = -np.diff(np.concatenate([[top], h[: down[0] + 1]]))
    return bool(steps.max() <= MAX_GAP_SHARE * top)


def peak_parts(
    xyz: np.ndarray, hag: np.ndarray, *, linkage: float, prominence: float, share: float, min_points: int = 1
) -> np.ndarray:
    """Label a cluster's points by the prominent peak they stand under.

    Parameters
    ----------
    xyz
        (n, 3) float64 coordinates of the cluster's points.
    hag
        (n,) their heights above ground.
    linkage
        The clustering's linkage (m): the points join a peak along the graph of points closer
        than it.
    prominence
        How far (m) a lower peak stands over its saddle at least (``towers.mast_prominence``).
    share
        The share of its height a lower peak stands over its saddle at least (``towers.peak_share``);
        0: never part.
    min_points
        Each part holds at least this many points.

    Returns
    -------
    numpy.ndarray
        (n,) int64 labels ``0..k-1``, one per peak (all 0: one tower).
    """
    labels = np.zeros(len(xyz), np.int64)
    if share <= 0 or len(xyz) < 2 * max(min_points, 1):
        return labels
    raster, origin = height_raster(xyz, hag)[0], xyz[:, :2].min(axis=0)
    size = int(round(MIN_TOP_GAP_M / CELL_M))
    highest = ndimage.maximum_filter(raster, size=size, mode="constant", cval=-np.inf)
    cand = np.argwhere(np.isfinite(raster) & (raster == highest))
    cand = cand[np.argsort(-raster[cand[:, 0], cand[:, 1]], kind="stable")]
    # a sparse tower leaves cells empty between its points (its crossarms at 2 pts/m²): the saddles
    # are read from a raster whose empty cells take the highest height within FILL_M
    filled = np.where(
        np.isfinite(raster),
        raster,
        ndimage.maximum_filter(raster, size=2 * round(FILL_M / CELL_M) + 1, mode="constant", cval=-np.inf),
    )
    filled[np.isneginf(filled)] = np.nan
    plan = cKDTree(xyz[:, :2])
    peaks: list[tuple[int, int]] = []
    for cell in map(tuple, cand):
        top = float(raster[cell])
        if any(CELL_M * np.hypot(*np.subtract(cell, p)) < MIN_TOP_GAP_M for p in peaks):
            continue
        if peaks and top < LOW_SHARE * float(raster[peaks[0]]):
            break
        if peaks:
            level = max(saddle(filled, cell, p) for p in peaks)
            if top - level < max(prominence, share * top):
                continue
            column = plan.query_ball_point(origin + (np.array(cell) + 0.5) * CELL_M, COLUMN_R_M)
            if not _has_body(hag[np.asarray(column, np.int64)], top):
                continue
        peaks.append(cell)
    while len(peaks) >= 2:
        centres = origin + (np.array(peaks) + 0.5) * CELL_M
        dist = np.stack([np.hypot(*(xyz[:, :2] - c).T) for c in centres], axis=1)
        nearest = dist.argmin(axis=1)
        seeds = np.flatnonzero(dist.min(axis=1) <= COLUMN_R_M)
        owner = nearest_seed(xyz, seeds, nearest[seeds], linkage, everywhere=True)
        failing = [
            k
            for k in range(len(peaks))
            if (own := owner == k).sum() < min_points
            or hag[own].min() > max(BAND_FLOOR_M, BODY_SHARE * float(hag[own].max()))
        ]
        if not failing:
            bases = np.array([base(xyz[owner == k, :2], hag[owner == k]) for k in range(len(peaks))])
            near = np.argwhere(np.triu(np.hypot(*(bases[:, None] - bases[None]).transpose(2, 0, 1)) < MIN_TOP_GAP_M, 1))
            failing = [int(near[:, 1].max())] if len(near) else []
        if not failing:
            return np.unique(owner, return_inverse=True)[1].astype(np.int64)
        del peaks[failing[-1]]
    return labels
