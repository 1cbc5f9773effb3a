"""The convex hull of points in plan: what footprints, the objects of the shape gate and the shape
check, the towers' feet and crowns are cut from (:func:`plan_hull`).

Part of the code that makes a tile's predictions (the shape gate's objects):
:data:`towerpipe.evaluation.predcache.INFERENCE_PACKAGES` lists it.
"""

from __future__ import annotations

import numpy as np
import shapely

__all__ = ["plan_hull"]


def plan_hull(xy: np.ndarray) -> shapely.Geometry:
    """The convex hull of points in plan: ``shapely.convex_hull(shapely.multipoints(xy))``.

    Parameters
    ----------
    xy
        ``(n, 2)`` plan coordinates.

    Returns
    -------
    shapely.Geometry
        A Polygon, or a LineString or Point where the points are collinear or one.

    Notes
    -----
    From two points on, the hull is taken of a line string through the points: GEOS finds the hull
    of the same coordinates, the same geometry byte for byte, without making a point geometry of
    each (a fifth of the time on an object of a few thousand points).
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return shapely.convex_hull(shapely.linestrings(xy) if len(xy) >= 2 else shapely.multipoints(xy))
