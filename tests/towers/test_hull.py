"""The plan hull (towerpipe.towers.hull): the convex hull of points, as a MultiPoint's."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from towerpipe.towers.hull import plan_hull


@pytest.mark.parametrize(
    "xy",
    [
        np.zeros((0, 2)),
        np.array([[3.0, 4.0]]),
        np.array([[3.0, 4.0], [3.0, 4.0], [3.0, 4.0]]),
        np.array([[0.0, 0.0], [1.0, 1.0]]),
        np.c_[np.arange(10.0), 2.0 * np.arange(10.0)],
        np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0], [0.5, 0.5], [1.0, 1.0]]),
        np.random.default_rng(0).normal(size=(3000, 2)) * 4.0 + [431_200.0, 4_581_700.0],
        np.round(np.random.default_rng(1).normal(size=(200, 2)) * 3.0, 1),
    ],
)
def test_the_plan_hull_is_the_hull_of_the_points_byte_for_byte(xy):
    """Taken through a line string, the hull is the one of the points as a MultiPoint: the same
    geometry, byte for byte (empty, one point, repeated points, collinear, duplicates, thousands)."""
    assert plan_hull(xy).wkb == shapely.convex_hull(shapely.multipoints(xy)).wkb
