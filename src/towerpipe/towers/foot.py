"""The foot of a tower: which of its lowest points are the tower and which stand around it.

A tower's lowest metres are where the segmenter is least sure: shrubs, grass and young trees
grow between and beside the legs, and at 1-8 m above the ground they look to a window much
like the legs themselves, so many of the points the segmenter paints there are the
vegetation's. The tower above is easy to read: its points a few metres higher outline it
(the legs and the faces of a lattice, the shaft of a pole, the posts of an H-frame). A
tower is hollow and its legs run down along its outline, splaying a little outward; the
vegetation fills the inside or stands beyond it. So a point below ``height`` is kept only
when it lies near the outline of the tower's points between ``height`` and ``height +
band``: no more than ``inside`` within it, no more than ``outside`` beyond it (metres,
horizontally). Fewer than ``outline_points`` points there do not outline a tower (a sparse
or a low one, where the band is its top): then every point stays.

Set on the calibration zones only (``towerpipe calibrate``, one run per setting given as an
extra config file; docs/model.md, "A tower's foot"). It picks the points a tower reports,
never which towers are: :func:`towerpipe.towers.extract.extract_towers` keeps every point
of a tower that trimming would leave with fewer than ``towers.min_points``. Points without
a height (NaN) are kept.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import shapely

from towerpipe.towers.hull import plan_hull

__all__ = ["foot_mask", "outline"]


def outline(x: np.ndarray, y: np.ndarray) -> shapely.Polygon | None:
    """The outline (convex hull) of points in plan; ``None`` where they outline nothing (fewer
    than three, or all on a line or at a point)."""
    hull = plan_hull(np.column_stack([x, y]))
    return hull if isinstance(hull, shapely.Polygon) else None


def foot_mask(x: np.ndarray, y: np.ndarray, hag: np.ndarray, foot: Mapping[str, float]) -> np.ndarray:
    """Which points of one tower to keep (the rule of ``towers.foot``).

    Parameters
    ----------
    x, y, hag
        The tower's points (metres; ``hag`` above the ground).
    foot
        ``height`` (m; 0 keeps every point), ``band`` (m), ``inside`` and ``outside`` (m),
        ``outline_points``: a point below ``height`` is kept when its horizontal distance to
        the outline (convex hull) of the points with ``height <= hag < height + band`` is at
        most ``inside`` within the outline or ``outside`` beyond it.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` bool. All true where the rule cannot judge: ``height`` 0, no point below it,
        or no outline above (fewer than ``outline_points`` points in the band, as on a sparse
        tower or one little higher than ``height``, or all of them on a line).
    """
    hag = np.asarray(hag, dtype=np.float64)
    keep = np.ones(hag.shape, bool)
    height, band = float(foot["height"]), float(foot["band"])
    low = hag < height
    above = (hag >= height) & (hag < height + band)
    if height <= 0 or not low.any() or above.sum() < int(foot["outline_points"]):
        return keep
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    tower = outline(x[above], y[above])
    if tower is None:
        return keep  # the points above on a line or at a point: no outline to measure from
    pts = shapely.points(x[low], y[low])
    # signed: negative within the outline
    dist = shapely.distance(tower.exterior, pts) * np.where(shapely.contains(tower, pts), -1.0, 1.0)
    keep[low] = (dist >= -float(foot["inside"])) & (dist <= float(foot["outside"]))
    return keep
