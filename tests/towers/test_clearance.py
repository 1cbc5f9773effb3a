"""The clearance of wire points over the vegetation below them."""

from __future__ import annotations

import numpy as np
import pytest

from towerpipe.towers import clearance
from towerpipe.towers.clearance import wire_clearance


@pytest.mark.parametrize("grid", [True, False], ids=["grid-of-cells", "sorted-keys"])
def test_clearance_is_the_brute_force_one(grid, monkeypatch):
    """The cell pre-filter of the vegetation drops no point within the radius (negative coordinates
    too), whether the cells beside the points are marked on a grid or kept as sorted keys."""
    if not grid:
        monkeypatch.setattr(clearance, "_GRID_MAX", 0)
    rng = np.random.default_rng(4)
    for off in (0.0, -1e4, 4e6):
        x, y, z = rng.uniform(-30, 30, (3, 400)) + np.array([[off], [off], [20.0]])
        vx, vy, vz = rng.uniform(-40, 40, (3, 5_000)) + np.array([[off], [off], [10.0]])
        d = np.hypot(x[:, None] - vx[None], y[:, None] - vy[None])
        below = np.where((d <= 2.0) & (vz[None] < z[:, None]), vz[None], -np.inf).max(axis=1)
        ref = np.where(np.isfinite(below), z - below, np.nan)
        got = wire_clearance(x, y, z, vx, vy, vz, 2.0)
        assert np.isfinite(got).sum() > 100
        np.testing.assert_array_equal(got, ref)
