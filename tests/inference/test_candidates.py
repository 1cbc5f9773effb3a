"""Tests of the candidate windows (towerpipe.inference.candidates): height peaks and the windows centred on them."""

from __future__ import annotations

import numpy as np
import pytest

from towerpipe.inference.candidates import PEAK_RADIUS, candidate_windows, height_peaks


def test_height_peaks_find_tower_tops_not_wires_or_crowns():
    """A tower top stands out of its crossarms and the conductors sagging away from it; a low
    plateau gives one peak; everything under min_height is ignored."""
    rng = np.random.default_rng(0)
    parts = []
    for tx in (100.0, 400.0):  # two towers, 30 m, a span apart
        h = rng.uniform(0, 30, 300)
        parts.append(np.c_[tx + rng.uniform(-2, 2, 300) * (1 - h / 40), 50 + rng.uniform(-2, 2, 300), h])
    s = np.linspace(0, 300, 600)  # a conductor sagging between them
    parts.append(np.c_[100 + s, np.full_like(s, 55.0), 26 - 0.0004 * s * (300 - s)])
    parts.append(np.c_[rng.uniform(0, 500, 3000), rng.uniform(0, 100, 3000), rng.uniform(0, 6, 3000)])  # shrubs
    roof = np.c_[rng.uniform(250, 270, 400), rng.uniform(80, 90, 400), np.full(400, 12.0)]  # a flat roof
    parts.append(roof)
    p = np.concatenate(parts)
    keys, centers, heights = height_peaks(p[:, 0], p[:, 1], p[:, 2], min_height=10.0)
    assert len(keys) == 3
    tops = centers[heights > 20]
    assert sorted(np.round(tops[:, 0] / 10).astype(int).tolist()) == [10, 40]
    assert np.all(np.abs(tops[:, 1] - 50) < 3)
    assert PEAK_RADIUS == 10.0 and heights.min() == pytest.approx(12.0)


def test_candidate_windows_need_core_points_and_keep_canonical_order():
    rng = np.random.default_rng(1)
    x = np.r_[rng.uniform(0, 10, 200), rng.uniform(200, 210, 200)]
    y = rng.uniform(0, 10, 400)
    h = np.r_[rng.uniform(0, 30, 200), rng.uniform(0, 30, 200)]
    core = x < 100  # the second object is buffer only
    cw = candidate_windows(x, y, h, core, window=40.0, min_height=10.0)
    assert len(cw) == 1 and cw.core_counts[0] == 200 == cw.counts[0]
    perm = rng.permutation(400)
    canon = np.argsort(perm)  # canonical order = the original order
    cw2 = candidate_windows(x[perm], y[perm], h[perm], core[perm], canonical_order=canon)
    np.testing.assert_array_equal(perm[cw2.indices(0)], cw.indices(0))
    assert len(cw.select(np.array([True]))) == 1
