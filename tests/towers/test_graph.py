"""The linkage graph of a cluster's points (towerpipe.towers.graph)."""

from __future__ import annotations

import numpy as np

from towerpipe.towers.graph import components, nearest_seed


def test_components_label_joined_nodes_alike():
    lab = components(5, np.array([[0, 1], [1, 2], [3, 4]]))
    assert lab[0] == lab[1] == lab[2] != lab[3] == lab[4]
    assert components(0, np.empty((0, 2), int)).size == 0


def test_nearest_seed_follows_the_graph_and_stops_at_the_limit():
    """Points join the seed nearest along links shorter than the linkage, not the nearest in space;
    a point beyond the limit, or linked to no seed, is not reached (-1)."""
    # a hook: 0 -> 5 along x, then back towards seed B at x=2, y=2 (1 m steps)
    hook = np.array([[x, 0.0, 0.0] for x in range(6)] + [[5.0, 1.0, 0.0], [5.0, 2.0, 0.0], [4.0, 2.0, 0.0]])
    seed_b = np.array([[2.0, 2.6, 0.0]])  # 2.6 m from (2, 0): no link at 1.5 m
    far = np.array([[40.0, 0.0, 0.0]])
    xyz = np.r_[hook, seed_b, far]
    b = len(hook)
    lab = nearest_seed(xyz, np.array([0, b]), np.array([7, 9]), 1.5)
    assert (lab[:b] == 7).all()  # (4, 2) is 2.1 m from B in space, but linked only to A's chain
    assert lab[b] == 9 and lab[-1] == -1
    short = nearest_seed(xyz, np.array([0]), np.array([7]), 1.5, limit=3.5)
    assert (short[:4] == 7).all() and (short[4:] == -1).all()


def test_everywhere_gives_unreached_points_the_nearest_seed_in_3d():
    """A point no path reaches (beyond ``linkage`` of every other) takes the seed nearest in 3-D;
    the reached ones keep the seed nearest along the graph."""
    xyz = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [10, 0, 0], [30, 0, 0]])
    seeds, labels = np.array([0, 3]), np.array([7, 9])
    np.testing.assert_array_equal(nearest_seed(xyz, seeds, labels, 1.5), [7, 7, 7, 9, -1])
    np.testing.assert_array_equal(nearest_seed(xyz, seeds, labels, 1.5, everywhere=True), [7, 7, 7, 9, 9])
