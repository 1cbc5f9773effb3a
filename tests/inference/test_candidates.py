"""Tests of the candidate windows (towerpipe.inference.candidates): height peaks and the windows centred on them."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import tower_among_crowns, towers_side_by_side
from towerpipe.inference.candidates import (
    PEAK_RADIUS,
    STEM_PAINTED,
    candidate_windows,
    disk_maximum,
    height_peaks,
    segmented_windows,
    stem_columns,
    stems_beside,
)


@pytest.mark.parametrize(
    ("shape", "radius", "res"),
    [
        ((580, 580), 10.0, 1.0),
        ((37, 91), 10.0, 1.0),
        ((5, 3), 10.0, 1.0),
        ((1, 40), 10.0, 1.0),
        ((90, 70), 3.5, 1.0),
        ((64, 64), 7.0, 1.0),
        ((60, 50), 10.0, 0.5),
        ((40, 40), 2.6, 0.7),
    ],
)
def test_disk_maximum_is_the_2d_maximum_filter_of_the_disk(shape, radius, res):
    """The height peaks' disk maximum, as runs of rows, is ``scipy.ndimage.maximum_filter`` over the
    disk footprint, cell for cell (empty cells ``-inf``, nothing beyond the raster's edge)."""
    from scipy import ndimage

    rng = np.random.default_rng(int(radius * 10) + shape[0])
    r = (rng.random(shape) * 40).astype(np.float32)
    r[rng.random(shape) < 0.5] = -np.inf
    k = int(np.ceil(radius / res))
    disk = np.hypot(*np.mgrid[-k : k + 1, -k : k + 1]) * res <= radius
    want = ndimage.maximum_filter(r, footprint=disk, mode="constant", cval=-np.inf)
    got = disk_maximum(r, radius, res)
    assert got.dtype == r.dtype
    np.testing.assert_array_equal(got, want)


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
    assert heights.min() == pytest.approx(12.0)


def test_a_small_tower_among_higher_crowns_is_its_own_peak():
    """In woodland a 16 m lattice has 19 m crowns of 3 m radius 11 m away: within 7 m it stands
    alone and makes a candidate; within 10 m (PEAK_RADIUS) the crowns' edges hide it."""
    p = tower_among_crowns()
    _, centers, heights = height_peaks(p[:, 0], p[:, 1], p[:, 2], min_height=10.0, radius=7.0)
    at_tower = np.hypot(centers[:, 0] - 50, centers[:, 1] - 50) < 1.5
    assert at_tower.sum() == 1 and heights[at_tower][0] == pytest.approx(16.0, abs=0.3)
    _, centers, _ = height_peaks(p[:, 0], p[:, 1], p[:, 2], min_height=10.0)
    assert PEAK_RADIUS == 10.0 and not (np.hypot(centers[:, 0] - 50, centers[:, 1] - 50) < 1.5).any()


def test_candidate_windows_need_core_points_and_keep_canonical_order():
    rng = np.random.default_rng(1)
    x = np.r_[rng.uniform(0, 5, 200), rng.uniform(200, 205, 200)]
    y = rng.uniform(0, 5, 400)
    h = np.r_[rng.uniform(0, 30, 200), rng.uniform(0, 30, 200)]
    core = x < 100  # the second object is buffer only
    cw = candidate_windows(x, y, h, core, window=40.0, min_height=10.0)
    assert len(cw) == 1 and cw.core_counts[0] == 200 == cw.counts[0]
    perm = rng.permutation(400)
    canon = np.argsort(perm)  # canonical order = the original order
    cw2 = candidate_windows(x[perm], y[perm], h[perm], core[perm], canonical_order=canon)
    np.testing.assert_array_equal(perm[cw2.indices(0)], cw.indices(0))
    assert len(cw.select(np.array([True]))) == 1


def test_window_counts_and_points_are_those_of_the_square_around_each_centre():
    """The counts are taken without listing any window's points, and a window's points are found
    when asked for: both are those of the square of side ``window`` around its centre (edges
    included), core points counted apart, in the canonical order."""
    rng = np.random.default_rng(7)
    n = 20_000
    x, y = rng.uniform(0, 300, n), rng.uniform(0, 300, n)
    h = rng.uniform(0, 12, n)
    tops = rng.choice(n, 40, replace=False)
    h[tops] = rng.uniform(15, 40, 40)
    x[:2000] = np.floor(x[:2000]) + 0.5  # on a window's edge: the centres are a 1 m raster's cell centres
    core = (x > 40) & (x < 260) & (y > 40) & (y < 260)
    canon = rng.permutation(n)
    cw = candidate_windows(x, y, h, core, window=40.0, min_height=10.0, min_points=5, canonical_order=canon)
    assert len(cw) > 10
    rank = np.empty(n, np.int64)
    rank[canon] = np.arange(n)
    assert any(((np.abs(x - cx) == 20.0) & (np.abs(y - cy) <= 20.0)).any() for cx, cy in cw.centers)  # on an edge
    for i in range(len(cw)):
        cx, cy = cw.center(i)
        inside = np.flatnonzero((np.abs(x - cx) <= 20.0) & (np.abs(y - cy) <= 20.0))
        want = inside[np.argsort(rank[inside], kind="stable")]
        np.testing.assert_array_equal(cw.indices(i), want)
        assert cw.counts[i] == len(inside) and cw.core_counts[i] == core[inside].sum() > 0
    # the peaks whose square holds too few points or no core point have no window
    _, centers, _ = height_peaks(x, y, h, min_height=10.0, radius=PEAK_RADIUS)
    square = (np.abs(x[None] - centers[:, :1]) <= 20.0) & (np.abs(y[None] - centers[:, 1:]) <= 20.0)
    has_window = (square.sum(1) >= 5) & (square & core[None]).any(1)
    assert 0 < has_window.sum() < len(centers)
    np.testing.assert_array_equal(cw.centers, centers[has_window])


def test_a_tower_hidden_by_crowns_gets_a_secondary_window_of_limited_reach():
    """The hidden tower's peak within the secondary radius becomes a window whose segmentation
    counts near its centre only; the primary peaks keep an unlimited reach; without secondary
    candidates the windows are the primary peaks'."""
    p = tower_among_crowns()
    core = np.ones(len(p), bool)
    primary = candidate_windows(p[:, 0], p[:, 1], p[:, 2], core, secondary_radius=0.0)
    both = candidate_windows(p[:, 0], p[:, 1], p[:, 2], core, secondary_radius=7.0, secondary_reach=6.0)
    assert np.isinf(primary.reach).all()
    assert not (np.hypot(*(primary.centers - 50).T) < 1.5).any()
    at_tower = np.hypot(*(both.centers - 50).T) < 1.5
    assert at_tower.sum() == 1 and both.reach[at_tower][0] == 6.0
    # every primary window is kept, with its reach
    assert {tuple(k) for k in primary.keys} <= {tuple(k) for k in both.keys}
    assert np.isinf(both.reach[~at_tower]).sum() == len(primary)
    assert both.select(at_tower).reach.tolist() == [6.0]


def test_columns_are_tower_bodies_not_crossarms_wires_or_roofs():
    """A lattice's body fills the height from the floor to its top; a crossarm, a conductor and a
    roof lie in a bin or two. The lower tower of a pair, under its neighbour's crossarms, is a column."""
    p = towers_side_by_side()
    centres, tops = stem_columns(p[:, 0], p[:, 1], p[:, 2], min_height=10.0)
    d = np.hypot(*(centres[:, None, :] - np.array([[50.0, 50.0], [60.5, 50.0]])[None]).transpose(2, 0, 1))
    assert len(centres) == 2 and (d.min(axis=0) < 1.5).all()  # d[column, tower]
    # a column's height is its highest point: the lower tower's column holds the crossarm above it
    lower = int(np.argmin(d[:, 1]))
    assert tops[1 - lower] == pytest.approx(56.0, abs=0.5) and 44.0 - 0.5 <= tops[lower] <= 52.0
    # nothing but the bodies: no column at the crossarm's ends, on the conductor or on the roof
    rest = p[(np.hypot(p[:, 0] - 50, p[:, 1] - 50) > 5) & (np.hypot(p[:, 0] - 60.5, p[:, 1] - 50) > 5)]
    assert len(stem_columns(rest[:, 0], rest[:, 1], rest[:, 2], min_height=10.0)[0]) == 0
    # lower than min_height, or nothing above the floor: no column
    assert len(stem_columns(p[:, 0], p[:, 1], p[:, 2], min_height=60.0)[0]) == 0
    low = p[p[:, 2] < 3.0]
    assert len(stem_columns(low[:, 0], low[:, 1], low[:, 2], min_height=2.0)[0]) == 0


def test_the_lower_tower_of_a_pair_gets_a_stem_window_of_limited_reach():
    """Under its neighbour's crossarms the lower tower is no height peak; with a stem gap its column
    becomes a stem window with the stem reach, and the higher tower's body, at its own peak, gives
    none. A peak within the gap (here a crossarm's end 3 m away, a secondary peak) takes its place."""
    p = towers_side_by_side()
    core = np.ones(len(p), bool)
    peaks = candidate_windows(p[:, 0], p[:, 1], p[:, 2], core)
    assert not (np.hypot(*(peaks.centers - [60.5, 50.0]).T) < 5).any()
    assert not peaks.stem.any()
    cw = candidate_windows(p[:, 0], p[:, 1], p[:, 2], core, stem_gap=8.0, stem_reach=5.0)
    at_lower = np.hypot(*(cw.centers - [60.5, 50.0]).T) < 1.5
    assert at_lower.sum() == 1 and cw.stem[at_lower].all() and cw.reach[at_lower].tolist() == [5.0]
    assert 44.0 - 0.5 <= cw.heights[at_lower][0] <= 52.0
    assert cw.stem.sum() == 1 and {tuple(k) for k in peaks.keys} <= {tuple(k) for k in cw.keys}
    assert cw.select(at_lower).stem.tolist() == [True]
    kw = {"secondary_radius": 3.0, "secondary_reach": 4.0}
    sec = candidate_windows(p[:, 0], p[:, 1], p[:, 2], core, **kw)
    assert (np.hypot(*(sec.centers - [60.5, 50.0]).T) < 5).any()  # the crossarm's end
    assert not candidate_windows(p[:, 0], p[:, 1], p[:, 2], core, stem_gap=8.0, stem_reach=5.0, **kw).stem.any()
    with pytest.raises(ValueError, match="stem_reach"):
        candidate_windows(p[:, 0], p[:, 1], p[:, 2], core, stem_gap=6.0)


def test_a_stem_is_segmented_beside_a_painted_tower_only():
    """A stem window needs STEM_PAINTED[0] painted points within PEAK_RADIUS of its centre: the
    neighbour of a pair is painted; a window that painted a few points (a crown's tip) is not enough."""
    rng = np.random.default_rng(0)
    tower = np.c_[rng.uniform(-2, 2, 200), rng.uniform(-2, 2, 200)]  # painted, around (0, 0)
    few = np.c_[60 + rng.uniform(-1, 1, STEM_PAINTED[0] - 1), rng.uniform(-1, 1, STEM_PAINTED[0] - 1)]
    stems = np.array([[10.5, 0.0], [PEAK_RADIUS + 2.5, 0.0], [61.0, 0.0], [200.0, 0.0]])
    assert stems_beside(stems, np.concatenate([tower, few])).tolist() == [True, False, False, False]
    assert stems_beside(stems, np.empty((0, 2))).tolist() == [False] * 4
    assert stems_beside(np.empty((0, 2)), tower).tolist() == []


def test_secondary_windows_near_a_segmented_primary_are_not_segmented():
    """A secondary peak within PEAK_RADIUS of a segmented primary peak is not read; farther, it is;
    where no primary passed, every secondary is read."""
    centers = np.array([[0.0, 0.0], [8.0, 0.0], [30.0, 0.0], [100.0, 0.0]])
    reach = np.array([np.inf, 4.0, 4.0, 4.0])
    assert segmented_windows(centers, reach, np.array([0, 1, 2])).tolist() == [0, 2]
    assert segmented_windows(centers, reach, np.array([1, 3])).tolist() == [1, 3]
    assert segmented_windows(centers, reach, np.array([], np.int64)).tolist() == []


def test_the_schema_bounds_secondary_peaks_by_the_peak_radius():
    """inference.secondary_radius names the peaks within it that are not peaks within PEAK_RADIUS:
    the schema's bound is that constant, and its default (on from 0.22.0, with rule 20) lies within it."""
    from conftest import REPO
    from towerpipe.config import SCHEMA_FILE, load_yaml

    schema = load_yaml(REPO / SCHEMA_FILE, "schema")
    sec = schema["properties"]["inference"]["properties"]["secondary_radius"]
    assert sec["exclusiveMaximum"] == PEAK_RADIUS and 0 < sec["default"] < PEAK_RADIUS


@pytest.mark.shared
def test_a_10_m_lattice_as_a_flight_samples_it_has_a_peak_at_the_shipped_floor():
    """The lowest towers the product looks for are 10 m high, but a flight seldom samples a small
    tower's very top: every real UAV and TS40K lattice scaled to 10 m and sampled at 10 pts/m² tops
    out under 10 m. A floor of 10 m gives none of them a window; the shipped floor
    (``inference.min_height``) gives each a peak on its axis, and the shipped floor of the tower
    rules (``towers.min_height``) keeps nearly all."""
    from conftest import UAV_TOWERS, schema_config
    from towerpipe.synth.real import airborne_resample, load_real_towers

    cfg = schema_config()
    floor, tower_floor = cfg["inference"]["min_height"], cfg["towers"]["min_height"]
    rng = np.random.default_rng(0)
    tops, found, at_10 = [], [], []
    for name, xyz in load_real_towers(UAV_TOWERS.parent):
        if not name.startswith(("uav:", "ts40k:")):
            continue
        h = xyz[:, 2] - xyz[:, 2].min()
        p = airborne_resample(np.c_[xyz[:, :2] * 10.0 / h.max(), h * 10.0 / h.max()], 10.0, rng)
        x, y, hag = p[:, 0], p[:, 1], p[:, 2]
        cx, cy = x.mean(), y.mean()
        tops.append(hag.max())
        _, centers, _ = height_peaks(x, y, hag, min_height=floor)
        found.append(len(centers) > 0 and np.hypot(centers[:, 0] - cx, centers[:, 1] - cy).min() < 3.0)
        at_10.append(len(height_peaks(x, y, hag, min_height=10.0)[1]) > 0)
    tops = np.asarray(tops)
    assert len(tops) >= 25 and (tops < 10.0).all(), tops
    assert all(found) and not any(at_10)
    assert np.mean(tops >= tower_floor) >= 0.85, np.sort(tops)
