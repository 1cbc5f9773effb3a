"""Constrained (3 m / 8 m bands) and random sampling to a fixed size."""

from __future__ import annotations

import numpy as np

from towerpipe.model.sampling import constrained_sample, random_sample


def _hag(n_low: int, n_mid: int, n_high: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    h = np.concatenate([rng.uniform(0, 2.99, n_low), rng.uniform(3, 7.99, n_mid), rng.uniform(8, 40, n_high)])
    return rng.permutation(h)


def _bands(h: np.ndarray) -> tuple[int, int, int]:
    return int((h < 3).sum()), int(((h >= 3) & (h < 8)).sum()), int((h >= 8).sum())


def test_only_low_points_removed_when_enough():
    h = _hag(3000, 1000, 500)
    idx = constrained_sample(h, 2048, np.random.default_rng(0))
    assert idx.shape == (2048,) and np.unique(idx).size == 2048
    assert _bands(h[idx]) == (2048 - 1500, 1000, 500)  # removed 2452 of the 3000 low points only


def test_low_band_emptied_then_mid_band_thinned():
    h = _hag(500, 3000, 1000)
    idx = constrained_sample(h, 2048, np.random.default_rng(0))
    assert np.unique(idx).size == 2048
    assert _bands(h[idx]) == (0, 1048, 1000)


def test_random_after_both_bands():
    h = _hag(300, 300, 5000)
    idx = constrained_sample(h, 2048, np.random.default_rng(0))
    assert np.unique(idx).size == 2048
    assert _bands(h[idx]) == (0, 0, 2048)


def test_deterministic_given_rng():
    h = _hag(3000, 1000, 500, seed=4)
    a = constrained_sample(h, 2048, np.random.default_rng(7))
    b = constrained_sample(h, 2048, np.random.default_rng(7))
    c = constrained_sample(h, 2048, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    np.testing.assert_array_equal(
        random_sample(5000, 2048, np.random.default_rng(1)), random_sample(5000, 2048, np.random.default_rng(1))
    )


def test_small_windows_padded_with_every_point_kept():
    h = _hag(100, 100, 100)
    idx = constrained_sample(h, 2048, np.random.default_rng(0))
    assert idx.shape == (2048,)
    assert np.array_equal(np.unique(idx), np.arange(300))  # every point at least once
    np.testing.assert_array_equal(idx[:300], np.arange(300))
    exact = constrained_sample(h, 300, np.random.default_rng(0))
    np.testing.assert_array_equal(exact, np.arange(300))


def test_random_sample_uniform_across_bands():
    h = _hag(6000, 2000, 2000)
    idx = random_sample(h.size, 2048, np.random.default_rng(0))
    assert np.unique(idx).size == 2048
    low, _, _ = _bands(h[idx])
    assert 0.5 < low / 2048 < 0.7  # ~60 % low points survive random sampling
