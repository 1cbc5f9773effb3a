"""The column of a tower: the faint points of its body that its cluster left out.

The segmenter paints the body of a tower it has not seen (a real lattice thinned to a few
points per m², a sparse pole) only in part above the clustering threshold: the rest of its
legs, faces and crossarms come out at 0.1-0.3, among the points of the cluster or right beside
them. Crowns painted at those probabilities stand beside a tower, rarely inside its outline.
So once a tower is accepted, the points at least ``min_height`` above the ground, within
``outside`` metres (horizontally) of the outline (convex hull) of its reported points, whose
probability reaches ``threshold`` are its points too. The foot below is left to the foot rule
(:mod:`towerpipe.towers.foot`), which runs first: grass and shrubs between the legs come out
of the segmenter at these probabilities too.

In :func:`towerpipe.towers.extract.extract_towers` the candidates are the gathered points (single-view
probability at or above the lowest of the clustering, rescue and column thresholds) that no accepted
tower's cluster holds (the point threshold has already judged those), from the blocks the tower's
cluster touches (the blocks whose jobs judge the tower); ``threshold`` applies to the view mean.

Set on the calibration zones only (``towerpipe calibrate``, one run per setting given as an
extra config file; docs/model.md, "A tower's column"). It picks the points a tower reports,
never which towers are.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import shapely

from towerpipe.towers.foot import outline

__all__ = ["column_mask"]


def column_mask(
    tower_x: np.ndarray,
    tower_y: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    hag: np.ndarray,
    prob: np.ndarray,
    column: Mapping[str, float],
) -> np.ndarray:
    """Which of the points ``x, y`` stand in the column of one tower (``towers.column``).

    Parameters
    ----------
    tower_x, tower_y
        The tower's reported points (metres).
    x, y, hag, prob
        The points to judge (metres; height above the ground; tower probability, 0-1).
    column
        ``threshold`` (0 takes no point), ``outside`` and ``min_height`` (m): a point is in the
        column when its probability reaches ``threshold``, it stands at least ``min_height``
        above the ground and it lies within the outline of the tower's points or at most
        ``outside`` beyond it.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` bool; all false where the rule is off or the tower's points outline nothing
        (fewer than three, or all on a line).
    """
    x = np.asarray(x, dtype=np.float64)
    take = np.zeros(x.shape, bool)
    threshold = float(column["threshold"])
    hull = outline(tower_x, tower_y) if threshold > 0 and x.size else None
    if hull is None:
        return take
    y = np.asarray(y, dtype=np.float64)
    outside = float(column["outside"])
    x0, y0, x1, y1 = hull.bounds
    near = (
        (np.asarray(prob) >= threshold)
        & (np.asarray(hag) >= float(column["min_height"]))
        & (x >= x0 - outside)
        & (x <= x1 + outside)
        & (y >= y0 - outside)
        & (y <= y1 + outside)
    )
    if near.any():
        take[near] = shapely.dwithin(hull, shapely.points(x[near], y[near]), outside)
    return take
