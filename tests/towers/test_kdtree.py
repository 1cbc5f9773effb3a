"""The tile trees answer every query as scipy's default tree does, up to the order of what they find."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from towerpipe.towers.kdtree import TILE_TREE, tile_tree


def test_tile_tree_finds_what_the_default_tree_finds():
    rng = np.random.default_rng(7)
    # clustered points with duplicates, as a tile's crowns and towers give them
    xy = np.concatenate([rng.normal(c, 3.0, (400, 2)) for c in rng.uniform(0, 200, (20, 2))])
    xy = np.concatenate([xy, xy[:300]])
    centers = rng.uniform(-10, 210, (80, 2))
    ref, got = cKDTree(xy), tile_tree(xy)
    assert not TILE_TREE["balanced_tree"]
    for r, p in ((1.0, 2.0), (7.5, 2.0), (20.0, np.inf)):
        np.testing.assert_array_equal(
            got.query_ball_point(centers, r, p=p, return_length=True),
            ref.query_ball_point(centers, r, p=p, return_length=True),
        )
        for a, b in zip(got.query_ball_point(centers, r, p=p), ref.query_ball_point(centers, r, p=p)):
            np.testing.assert_array_equal(np.sort(a), np.sort(b))
    pairs = got.sparse_distance_matrix(tile_tree(xy[:500]), 2.5, output_type="ndarray")
    ref_pairs = ref.sparse_distance_matrix(cKDTree(xy[:500]), 2.5, output_type="ndarray")
    assert sorted(pairs.tolist()) == sorted(ref_pairs.tolist())
