"""Training-time augmentation: geometry, and attribute dropout / corruption that spares shape."""

from __future__ import annotations

import numpy as np
import pytest

from towerpipe.model.features import FEATURE_SETS
from towerpipe.training.augment import OPERATIONS, attribute_groups, augment_geometry, corrupt_attributes

FULL = FEATURE_SETS["full"]  # x y z intensity green blue ndvi


def _batch(b=64, n=200, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.05, 0.95, (b, n, len(FULL))).astype(np.float32)
    lab = np.zeros((b, n), np.int64)
    lab[:, :40] = 1  # the tower's points
    x[:, :40, 3:] = 0.9  # a tower signature: bright, grey, low NDVI...
    x[:, 40:, 3:] = 0.2  # ...against its surroundings
    return x, lab


def test_groups_follow_the_attributes():
    assert attribute_groups(FULL) == {"intensity": [3], "rgb": [4, 5], "nir": [6]}
    assert attribute_groups(FEATURE_SETS["shape"]) == {}
    assert attribute_groups(FEATURE_SETS["geometry"]) == {"intensity": [3], "returns": [4, 5]}


def test_shape_columns_are_never_touched_and_p0_is_identity():
    x, lab = _batch()
    before = x.copy()
    corrupt_attributes(x, FULL, lab, 0.0, np.random.default_rng(1))
    np.testing.assert_array_equal(x, before)
    corrupt_attributes(x, FULL, lab, 1.0, np.random.default_rng(1))
    np.testing.assert_array_equal(x[..., :3], before[..., :3])
    assert not np.array_equal(x[..., 3:], before[..., 3:])


@pytest.mark.parametrize("op", OPERATIONS)
def test_each_operation(op):
    x, lab = _batch(b=4)
    before = x.copy()
    corrupt_attributes(x, FULL, lab, 1.0, np.random.default_rng(2), operations=(op,))
    col = x[..., 3]
    if op == "zero":
        assert (x[..., 3:] == 0).all()
    elif op == "constant":
        assert all(np.unique(x[i, :, 3]).size == 1 for i in range(4))
    elif op == "rescale":
        # one factor per window, drawn from 0.3-3 (clipped to the column's range): never the identity
        ratio = col / before[..., 3]
        unclipped = col < 3.0
        assert unclipped.all(axis=1).any()
        for i in range(4):
            r = ratio[i][unclipped[i]]
            assert np.allclose(r, r[0], atol=1e-5) and not np.isclose(r[0], 1.0, atol=1e-3)
            assert 0.3 - 1e-6 <= r[0] <= 3.0 + 1e-6
    elif op == "bits8":
        np.testing.assert_allclose(x[..., 4], before[..., 4] / 257, rtol=1e-6)
        np.testing.assert_allclose(x[..., 3], before[..., 3] / 256, rtol=1e-6)
    elif op == "permute":
        # the same values, moved among the points: the tower's bright values leave its 40 points
        np.testing.assert_allclose(np.sort(col, axis=1), np.sort(before[..., 3], axis=1))
        assert not np.array_equal(col, before[..., 3])
        assert (np.isclose(col[:, :40], 0.9).sum(axis=1) < 40).all()
    elif op == "swap":
        # the tower's points now carry its surroundings' values: the signature is gone
        assert np.allclose(x[:, :40, 3:], 0.2) and np.allclose(x[:, 40:, 3:], 0.2)


def test_corruption_rate_per_window_and_group():
    x, lab = _batch(b=2000, n=50)
    before = x.copy()
    corrupt_attributes(x, FULL, lab, 0.5, np.random.default_rng(3))
    changed = ~np.all(np.isclose(x[..., 3], before[..., 3]), axis=1)
    assert 0.35 < changed.mean() < 0.55  # permute/swap of equal values can look unchanged


def test_geometry_rotation_keeps_heights_and_radii():
    x, _ = _batch(b=8)
    r0 = np.hypot(x[..., 0], x[..., 1])
    z0 = x[..., 2].copy()
    augment_geometry(x, {"rotate": True, "scale": 0.0, "jitter_m": 0.0}, np.random.default_rng(4))
    np.testing.assert_allclose(np.hypot(x[..., 0], x[..., 1]), r0, rtol=1e-5)
    np.testing.assert_array_equal(x[..., 2], z0)
    augment_geometry(x, {"rotate": False, "scale": 0.2, "jitter_m": 0.0}, np.random.default_rng(4))
    f = x[..., 2] / z0
    assert np.allclose(f, f[:, :1]) and (np.abs(f - 1) <= 0.2 + 1e-6).all()
