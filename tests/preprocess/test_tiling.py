"""Tile grid, cores and neighbours."""

import numpy as np

from towerpipe.preprocess import tiling


def test_cores_partition_points_including_edges_and_strays():
    rng = np.random.default_rng(1)
    x = rng.uniform(400000, 401000, 5000)
    y = rng.uniform(4600000, 4600700, 5000)
    x[:3] = [400000.0, 400500.0, 401000.0]  # on tile and block edges
    x[3] = 401000.5  # beyond the header bounds: clipped into the edge tile
    grid = tiling.TileGrid((400000.0, 4600000.0, 401000.0, 4600700.0), 500.0)
    assert grid.shape == (2, 2) and grid.ids() == ["0_0", "1_0", "0_1", "1_1"]
    owners = np.stack([grid.core_mask(x, y, t) for t in grid.ids()])
    np.testing.assert_array_equal(owners.sum(axis=0), 1)  # every point in exactly one core


def test_no_sliver_tiles_and_tiles_not_larger_than_requested():
    assert tiling.tile_ids((0.0, 0.0, 200.0, 200.0), 200.0) == ["0_0"]
    grid = tiling.TileGrid((0.0, 0.0, 707.0, 300.0), 500.0)
    assert grid.shape == (2, 1)
    assert grid.cell == (353.5, 300.0)
    assert grid.core_box("1_0") == (353.5, 0.0, 707.0, 300.0)


def test_neighbours_and_tile_blocks():
    b = {"a": (0, 0, 1000, 1000), "b": (1000, 0, 2000, 1000), "c": (5000, 0, 6000, 1000), "d": (0, 1000, 1000, 2000)}
    assert tiling.neighbours("a", b, 40) == ["b", "d"]
    # with 250 m tiles, a tile in the middle of a needs no neighbour; one at its east edge needs b
    assert tiling.blocks_for_tile(b["a"], "1_1", 250.0, 40.0, b) == ["a"]
    assert tiling.blocks_for_tile(b["a"], "3_1", 250.0, 40.0, b) == ["a", "b"]


def test_plan_comes_from_the_points_never_from_a_header():
    import numpy as np

    from towerpipe.preprocess.tiling import TileGrid, occupied_tiles, plan_zone

    # a block of 1 km with one stray point 1,400 km away: 4 tiles and one more, not 2,800²
    x = np.r_[np.random.default_rng(0).uniform(0, 1000, 5000), 1.4e6]
    y = np.r_[np.random.default_rng(1).uniform(0, 1000, 5000), 1.4e6]
    grid = TileGrid((0.0, 0.0, float(x.max()), float(y.max())), 500.0)
    tiles = occupied_tiles(grid, x, y)
    assert len(tiles) <= 5 and grid.shape[0] > 2000
    metas = {
        "a": {"bounds": [0.0, 0.0, 1000.0, 1000.0], "tiles": ["0_0", "1_0", "0_1", "1_1"], "points": 10},
        "b": {"bounds": [1000.0, 0.0, 2000.0, 1000.0], "tiles": ["0_0", "1_0", "0_1", "1_1"], "points": 10},
        "c": {"bounds": [5000.0, 0.0, 6000.0, 1000.0], "tiles": ["0_0"], "points": 10},
        # a block that could not be split, whose header claims the whole country
        "bad": {"error": {"cause": "truncated"}, "header_bounds": [0.0, 0.0, 1.4e6, 1.4e6]},
    }
    plan = plan_zone(metas, 500.0, 40.0)["blocks"]
    assert plan["bad"]["tiles"] == [] and plan["bad"]["neighbours"] == []
    assert plan["a"]["neighbours"] == ["b"] and plan["c"]["neighbours"] == []
    assert plan["a"]["tile_blocks"]["1_0"] == ["a", "b"] and plan["a"]["tile_blocks"]["0_0"] == ["a"]
    assert all(p["missing_neighbours"] == ["bad"] for b, p in plan.items() if b != "bad")


def test_occupied_tiles_by_count_or_by_sort_are_the_same():
    """A block's few tiles are counted, a grid widened by a stray point is sorted: the same tiles."""
    import numpy as np

    from towerpipe.preprocess.tiling import TileGrid, occupied_tiles

    rng = np.random.default_rng(2)
    x, y = rng.uniform(0, 1000, 20_000), rng.uniform(0, 1000, 20_000)
    keep = ~((x > 500) & (y < 500))  # tile 1_0 left empty
    grid = TileGrid((0.0, 0.0, 1000.0, 1000.0), 250.0)
    want = sorted(
        {(int(a), int(b)) for a, b in zip(*grid.index(x[keep], y[keep]), strict=True)}, key=lambda t: (t[1], t[0])
    )
    assert occupied_tiles(grid, x[keep], y[keep], chunk=7_000) == [f"{a}_{b}" for a, b in want]
    assert "2_0" not in occupied_tiles(grid, x[keep], y[keep]) and len(want) == 12
