"""Tests of sliding-window membership (towerpipe.inference.windows) against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from towerpipe.inference.windows import sliding_windows


def _cloud(n=4000, seed=0, x0=400000.0, y0=4600000.0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(x0 - 40, x0 + 140, n)
    y = rng.uniform(y0 - 40, y0 + 140, n)
    core = (x >= x0) & (x < x0 + 100) & (y >= y0) & (y < y0 + 100)
    return x, y, core


def _brute(x, y, ox, oy, w):
    return np.flatnonzero((x >= ox) & (x < ox + w) & (y >= oy) & (y < oy + w))


@pytest.mark.parametrize("window,stride", [(40, 20), (40, 10), (30, 20), (40, 40), (25, 15)])
def test_membership_matches_brute_force(window, stride):
    x, y, core = _cloud()
    ws = sliding_windows(x, y, core, window=window, stride=stride)
    assert len(ws) > 0
    for i in range(len(ws)):
        ox, oy = ws.origin(i)
        assert ox % stride == 0 and oy % stride == 0  # global grid
        got = ws.indices(i)
        want = _brute(x, y, ox, oy, window)
        assert len(got) == len(np.unique(got)) == ws.counts[i]
        np.testing.assert_array_equal(np.sort(got), want)
        assert ws.core_counts[i] == core[want].sum() > 0
        cx, cy = ws.center(i)
        assert (cx, cy) == (ox + window / 2, oy + window / 2)
    # every core point is covered, by exactly as many windows as geometry allows
    mc = ws.membership_count()
    assert (mc[core] >= 1).all()
    if window % stride == 0:
        assert (mc[core] == (window // stride) ** 2).all()
    # windows with no core point are not produced: check every candidate origin nearby
    produced = {tuple(k) for k in ws.keys.tolist()}
    kx0, ky0 = int(np.floor((x.min() - window) / stride)), int(np.floor((y.min() - window) / stride))
    for kx in range(kx0, int(x.max() // stride) + 1):
        for ky in range(ky0, int(y.max() // stride) + 1):
            has_core = core[_brute(x, y, kx * stride, ky * stride, window)].any()
            assert has_core == ((kx, ky) in produced)


def test_min_points_and_empty_input():
    x, y, core = _cloud(n=300)
    ws_all = sliding_windows(x, y, core, min_points=1)
    ws = sliding_windows(x, y, core, min_points=15)
    assert len(ws) == int((ws_all.counts >= 15).sum()) < len(ws_all)
    assert (ws.counts >= 15).all()
    sel = ws_all.select(ws_all.counts >= 15)
    np.testing.assert_array_equal(sel.keys, ws.keys)
    e = sliding_windows(np.empty(0), np.empty(0), np.empty(0, bool))
    assert len(e) == 0 and list(e) == []
    none_core = sliding_windows(x, y, np.zeros(len(x), bool))
    assert len(none_core) == 0


def test_canonical_order_makes_window_lists_order_independent():
    x, y, core = _cloud(n=2000, seed=3)
    ident = np.arange(len(x)) * 7 + 11  # stable identity of each point
    perm = np.random.default_rng(1).permutation(len(x))
    a = sliding_windows(x, y, core, canonical_order=np.argsort(ident))
    b = sliding_windows(x[perm], y[perm], core[perm], canonical_order=np.argsort(ident[perm]))
    np.testing.assert_array_equal(a.keys, b.keys)
    for i in range(len(a)):
        np.testing.assert_array_equal(ident[a.indices(i)], ident[perm][b.indices(i)])


def test_negative_coordinates_and_bad_arguments():
    x, y, core = _cloud(x0=-50.0, y0=-75.0, seed=5)
    ws = sliding_windows(x, y, core, window=40, stride=20)
    for i in range(len(ws)):
        ox, oy = ws.origin(i)
        np.testing.assert_array_equal(np.sort(ws.indices(i)), _brute(x, y, ox, oy, 40))
    with pytest.raises(ValueError):
        sliding_windows(x, y, core, window=20, stride=40)
    with pytest.raises(ValueError):
        sliding_windows(x, y[:-1], core)


def test_classifier_pass_refuses_only_unsure_windows_the_shape_gate_scored_low():
    from towerpipe.inference.windows import classifier_pass

    prob = np.array([0.005, 0.02, 0.02, 0.02, 0.5, 0.5])
    shape = np.array([0.9, 0.005, 0.02, np.nan, 0.005, 0.9])
    # under the gate: never; unsure (0.01 <= p < 0.03) with a low shape score: refused; not scored: passed
    assert classifier_pass(prob, shape, 0.01, 0.03, 0.01).tolist() == [False, False, True, True, True, True]
    # the condition off: the plain gate
    plain = [False, True, True, True, True, True]
    assert classifier_pass(prob, shape, 0.01, 0.03, 0.0).tolist() == plain
    assert classifier_pass(prob, shape, 0.01, 0.01, 0.01).tolist() == plain
    assert classifier_pass(prob, None, 0.01, 0.03, 0.01).tolist() == plain
