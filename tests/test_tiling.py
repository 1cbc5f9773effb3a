"""Tile grid, cores and neighbours."""

import numpy as np

from towerpipe import tiling


def test_tile_ids_cover_bounds_and_cores_partition_points():
    rng = np.random.default_rng(1)
    x = rng.uniform(400010, 400990, 5000)
    y = rng.uniform(4600000, 4600700, 5000)
    x[:3] = [400000.0, 400500.0, 400990.0]  # on tile edges
    ids = tiling.tile_ids((x.min(), y.min(), x.max(), y.max()), 250.0)
    owners = np.stack([tiling.core_mask(x, y, t, 250.0) for t in ids])
    np.testing.assert_array_equal(owners.sum(axis=0), 1)  # every point in exactly one core


def test_negative_tile_ids_round_trip():
    assert tiling.parse_tile_id("-3_7") == (-3, 7)
    assert tiling.tile_bounds("-1_0", 100.0) == (-100.0, 0.0, 0.0, 100.0)


def test_neighbours_and_tile_blocks():
    b = {"a": (0, 0, 1000, 1000), "b": (1000, 0, 2000, 1000), "c": (5000, 0, 6000, 1000),
         "d": (0, 1000, 1000, 2000)}
    assert tiling.neighbours("a", b, 40) == ["b", "d"]
    # a tile in the middle of a needs no neighbour; one at its east edge needs b
    assert tiling.blocks_for_tile("1_1", 250.0, 40.0, b) == ["a"]
    assert tiling.blocks_for_tile("3_1", 250.0, 40.0, b) == ["a", "b"]
