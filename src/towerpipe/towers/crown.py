"""The crowns beside a tower: which of its lower points stand out from the tower above them.

In woodland the segmenter paints the crowns that stand beside a tower with it (a window
centred on a tower reads much of what is near its centre as the tower), and they come out as
part of the tower's cluster: 6-18 m up, a few metres from its legs and faces. A tower
narrows upward or stands straight, and what is wider than its body is high up (the crossarms,
the conductors' insulators); the crowns beside it are lower than its upper half and stand
beyond the outline of the tower above them. So a point lower than ``below`` of the tower's
height is kept only when it lies no more than ``beyond`` (metres, horizontally) outside the
outline (convex hull) of the tower's points at least ``height`` metres higher. Fewer than
``outline_points`` points that high do not outline a tower (near the top of a sparse or low
one): such points stay.

Set on the calibration zones only (docs/model.md, "Crowns beside a tower"). Like
:mod:`towerpipe.towers.foot` it picks the points a tower reports, never which towers are:
:func:`towerpipe.towers.extract.extract_towers` keeps every point of a tower that trimming
would leave with fewer than ``towers.min_points``. Points without a height (NaN) are kept.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import shapely

from towerpipe.towers.hull import plan_hull

__all__ = ["crown_mask"]


def crown_mask(x: np.ndarray, y: np.ndarray, hag: np.ndarray, crowns: Mapping[str, float]) -> np.ndarray:
    """Which points of one tower to keep (the rule of ``towers.crowns``).

    Parameters
    ----------
    x, y, hag
        The tower's points (metres; ``hag`` above the ground).
    crowns
        ``beyond`` (m; 0 keeps every point), ``height`` (m), ``below`` (share of the tower's
        height, its highest ``hag``) and ``outline_points``: a point lower than ``below`` of the
        tower's height is kept when its horizontal distance to the outline (convex hull) of the
        tower's points at least ``height`` higher is at most ``beyond``. The points are judged
        by the metre of height they stand in (the outline of each metre's points is that of
        the points ``height`` above the metre's floor).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` bool. True where the rule cannot judge: ``beyond`` 0, no height, or too few
        points above to outline the tower.
    """
    hag = np.asarray(hag, dtype=np.float64)
    keep = np.ones(hag.shape, bool)
    beyond = float(crowns["beyond"])
    known = np.isfinite(hag)
    if beyond <= 0 or not known.any():
        return keep
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    height, need = float(crowns["height"]), int(crowns["outline_points"])
    judged = known & (hag < float(crowns["below"]) * hag[known].max())
    level = np.floor(np.where(judged, hag, 0.0))
    for floor in np.unique(level[judged]):
        above = known & (hag >= floor + height)
        if above.sum() < need:
            break  # the floors ascend: none higher has enough points above it either
        tower = plan_hull(np.column_stack([x[above], y[above]]))
        here = np.flatnonzero(judged & (level == floor))
        keep[here] = shapely.distance(tower, shapely.points(x[here], y[here])) <= beyond
    return keep
