"""Tile files: the labelled points of a block's tiles, each point once."""

from __future__ import annotations

import numpy as np

from towerpipe.io.tiles import TILE_ARRAYS, Tile, empty_arrays, labelled_points, save_tile


def a_tile(path, blocks, block_id, point_index, classification, x):
    n = len(x)
    arrays = empty_arrays(n)
    arrays.update(
        x=np.asarray(x, "f8"),
        y=np.zeros(n),
        z=np.asarray(x, "f8") + 100.0,
        hag=np.asarray(x, "f4"),
        block_id=np.asarray(block_id, "i4"),
        point_index=np.asarray(point_index, "i8"),
        classification=np.asarray(classification, "u1"),
    )
    assert set(arrays) == set(TILE_ARRAYS)
    save_tile(path, Tile(arrays, {"blocks": blocks, "zone": "z", "block": blocks[0], "tile": "0_0"}))
    return str(path)


def test_labelled_points_of_overlapping_tiles_are_each_kept_once(tmp_path):
    # point 3 of block a is in both tiles (one's core, the other's buffer); block b lends a buffer
    t1 = a_tile(tmp_path / "t1.npz", ["a", "b"], [0, 0, 1, 0], [1, 3, 3, 4], [15, 15, 15, 2], [1.0, 3.0, 30.0, 4.0])
    t2 = a_tile(tmp_path / "t2.npz", ["a"], [0, 0], [3, 5], [15, 15], [3.0, 5.0])
    t3 = a_tile(tmp_path / "t3.npz", ["a"], [0], [6], [2], [6.0])
    got = labelled_points([t1, t2, t3], 15)
    assert sorted(got) == ["hag", "x", "y", "z"]
    assert sorted(got["x"].tolist()) == [1.0, 3.0, 5.0, 30.0]  # a:1, a:3 once, b:3, a:5
    assert all(v.dtype == np.float64 for v in got.values())
    assert np.array_equal(got["z"], got["x"] + 100.0)
    assert labelled_points([t3], 15)["x"].shape == (0,)
