"""Tests of towerpipe.towers.coverage: where the data is around a tower, and the tile context."""

from __future__ import annotations

import numpy as np

from towerpipe.towers.coverage import Coverage, TileContext, tile_density

X0, Y0 = 400_000.0, 4_600_000.0


def test_tile_context_picks_the_tile_holding_the_centre(tmp_path):
    from towerpipe.io.tiles import Tile, empty_arrays, save_tile

    paths = []
    for k, x0 in enumerate((X0, X0 + 500)):
        a = empty_arrays(3)
        a["x"][:] = x0 + np.array([10.0, 20.0, 30.0])
        a["y"][:] = Y0 + 5
        a["model_input"][:] = [True, True, False]
        path = tmp_path / f"t{k}.npz"
        meta = {
            "core_bounds": [x0, Y0, x0 + 500, Y0 + 500],
            "buffer": 40.0,
            "counts": {"points": 3, "core": 3 * (k + 1)},
        }
        save_tile(path, Tile(a, meta))
        paths.append(str(path))
    ctx = TileContext(paths)
    arrays, coverage = ctx(X0 + 600, Y0 + 10)
    np.testing.assert_array_equal(arrays["x"], X0 + 500 + np.array([10.0, 20.0]))
    assert arrays["density"] == 6 / 500**2  # the tile's own (the shape check thins a dense tile's objects)
    # the data is where the tile's points are (all three, the non-model-input one too)
    assert coverage.contains(np.array([X0 + 535.0, X0 + 600.0]), np.array([Y0 + 5.0, Y0 + 5.0])).tolist() == [
        True,
        False,
    ]
    assert ctx(X0 - 1, Y0) is None


def test_tile_context_reads_each_tile_once_for_clusters_in_any_order(tmp_path):
    # the towers job visits clusters in label order: keeping only the last tile read each
    # tile again for nearly every cluster (240 reads of 4 tiles on the 1 km² benchmark block)
    from towerpipe.io.tiles import Tile, empty_arrays, save_tile

    paths = []
    for k, x0 in enumerate((X0, X0 + 500, X0 + 1000)):
        a = empty_arrays(2)
        a["x"][:], a["y"][:], a["model_input"][:] = x0 + 10, Y0 + 10, True
        path = tmp_path / f"t{k}.npz"
        save_tile(path, Tile(a, {"core_bounds": [x0, Y0, x0 + 500, Y0 + 500], "buffer": 40.0}))
        paths.append(str(path))
    ctx = TileContext(paths, keep_tiles=3)
    for _ in range(5):
        for x0 in (X0, X0 + 1000, X0 + 500):
            assert ctx(x0 + 100, Y0 + 100) is not None
    assert ctx.reads == 3
    one = TileContext(paths, keep_tiles=1)  # the least recently used tile is dropped
    for x0 in (X0, X0 + 500, X0):
        one(x0 + 100, Y0 + 100)
    assert one.reads == 3


def test_tile_context_skips_a_tile_without_points(tmp_path):
    # a block whose split failed used to leave an empty tile over its neighbour's place:
    # listed first, it hid the neighbour's tile and its tower lost its conductor support
    from towerpipe.io.tiles import Tile, empty_arrays, save_tile

    empty = tmp_path / "a_failed.npz"
    save_tile(
        empty,
        Tile(empty_arrays(0), {"core_bounds": [X0, Y0, X0 + 500, Y0 + 500], "buffer": 40.0, "counts": {"points": 0}}),
    )
    a = empty_arrays(2)
    a["x"][:], a["y"][:], a["model_input"][:] = X0 + 10, Y0 + 10, True
    good = tmp_path / "b_good.npz"
    save_tile(good, Tile(a, {"core_bounds": [X0, Y0, X0 + 500, Y0 + 500], "buffer": 40.0, "counts": {"points": 2}}))
    arrays, _ = TileContext([str(empty), str(good)])(X0 + 100, Y0 + 100)
    assert len(arrays["x"]) == 2


def ring_bins(cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    """The 80-160 m ring's bin centres of wire_support's 72 sectors (20 degrees, every 5)."""
    mid = np.radians(np.arange(0.0, 360.0, 5.0) + 10.0)
    rc = 80.0 + 10.0 * (np.arange(8) + 0.5)
    return cx + np.cos(mid)[:, None] * rc, cy + np.sin(mid)[:, None] * rc


def test_lines_seen_inside_at_an_edge_at_a_corner_and_in_a_strip():
    """Share of the lines through a tower with one of their two directions in the survey."""
    one = np.zeros(1)
    zone = Coverage(one, one, survey=[(X0, Y0, X0 + 1000, Y0 + 1000)])
    assert zone.lines_seen(*ring_bins(X0 + 500, Y0 + 500), 4) == 1.0  # inside
    assert zone.lines_seen(*ring_bins(X0 + 500, Y0 + 5), 4) == 1.0  # at the straight edge: the inner half
    corner = zone.lines_seen(*ring_bins(X0 + 5, Y0 + 5), 4)
    assert 0.45 < corner < 0.6  # about half the directions leave on both sides
    strip = Coverage(one, one, survey=[(X0, Y0 - 20, X0 + 1000, Y0 + 20)])  # a corridor 40 m wide
    assert strip.lines_seen(*ring_bins(X0 + 500, Y0), 4) < 0.2  # only the lines along it
    assert Coverage(one, one).lines_seen(*ring_bins(X0, Y0), 4) == 1.0  # no survey given: everything


def test_a_tiles_density_is_its_core_points_over_its_core_box():
    # as the verifier's training measures it: every core point, ground included
    meta = {"core_bounds": [X0, Y0, X0 + 500, Y0 + 250], "counts": {"core": 2_500_000, "ground_core": 1_000_000}}
    assert tile_density(meta) == 20.0
    assert np.isnan(tile_density({"core_bounds": [X0, Y0, X0 + 1, Y0 + 1]}))
    assert np.isnan(tile_density({"counts": {"core": 5}}))
