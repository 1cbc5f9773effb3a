"""Tests of towerpipe.towers.wires: conductor support of tower candidates."""

from __future__ import annotations

import numpy as np

from towerpipe.towers.wires import conductor_directions, conductor_heights, wire_points, wire_support

X0, Y0 = 400_000.0, 4_600_000.0


def conductor(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    z0: float,
    *,
    sag: float = 6.0,
    step: float = 0.7,
    rng: np.random.Generator,
) -> np.ndarray:
    """Points along one sagging conductor (about one return per ``step`` m)."""
    n = int(np.hypot(x1 - x0, y1 - y0) / step)
    s = np.sort(rng.random(n))
    z = z0 - sag * 4 * s * (1 - s)
    return np.column_stack([x0 + s * (x1 - x0), y0 + s * (y1 - y0), z]) + rng.normal(0, 0.03, (n, 3))


def line_through(
    cx: float,
    cy: float,
    angle: float,
    *,
    arms=(-6.0, 0.0, 6.0),
    z0: float = 25.0,
    length: float = 300.0,
    rng: np.random.Generator,
) -> np.ndarray:
    """Three conductors through (cx, cy) (crossarm offsets ``arms``), both ways."""
    d = np.array([np.cos(angle), np.sin(angle)])
    n = np.array([-d[1], d[0]])
    parts = []
    for a in arms:
        p0 = np.array([cx, cy]) + a * n - length * d
        p1 = np.array([cx, cy]) + a * n + length * d
        parts.append(conductor(*p0, *p1, z0, rng=rng))
    return np.concatenate(parts)


def spans(cx: float, cy: float, top: float, rng: np.random.Generator) -> np.ndarray:
    """Three conductors leaving (cx, cy) at height ``top`` both ways along x, 300 m spans sagging 8 m
    (flat ground at 0: z is HAG)."""
    parts = []
    for dy in (-5.0, 0.0, 5.0):
        for far in (cx - 300.0, cx + 300.0):
            parts.append(conductor(cx, cy + dy, far, cy + dy, top, sag=8.0, rng=rng))
    return np.concatenate(parts)


def canopy(cx: float, cy: float, r: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """A forest: dense points from 3 to 20 m over a disc."""
    a, d = rng.uniform(0, 2 * np.pi, n), r * np.sqrt(rng.random(n))
    return np.column_stack([cx + d * np.cos(a), cy + d * np.sin(a), rng.uniform(3, 20, n)])


def support(pts: np.ndarray, cx: float, cy: float, **kw) -> float:
    return wire_support(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 2], cx, cy, **kw)  # flat ground: z is HAG


def test_wire_points_find_conductors_not_crowns():
    rng = np.random.default_rng(0)
    wires = line_through(X0, Y0, 0.3, rng=rng)
    trees = canopy(X0 + 500, Y0, 40.0, 40_000, rng)
    pts = np.concatenate([wires, trees])
    mask, direction = wire_points(pts[:, 0], pts[:, 1], pts[:, 2])
    assert mask[: len(wires)].mean() > 0.8
    assert mask[len(wires) :].mean() < 0.01
    d = direction[: len(wires)][mask[: len(wires)]]
    assert np.median(np.abs(d @ np.array([np.cos(0.3), np.sin(0.3)]))) > 0.99


def test_judged_points_get_the_answer_of_a_full_search():
    """``judge`` (a tile's core) leaves the others as neighbours only: same answers where judged."""
    rng = np.random.default_rng(3)
    pts = np.concatenate([line_through(X0, Y0, 0.7, rng=rng), canopy(X0 + 60, Y0, 50.0, 30_000, rng)])
    judge = pts[:, 0] < X0 + 40
    full, full_dir = wire_points(pts[:, 0], pts[:, 1], pts[:, 2])
    part, part_dir = wire_points(pts[:, 0], pts[:, 1], pts[:, 2], judge=judge)
    assert full[judge].sum() > 100 and full[~judge].any()  # wires on both sides, crowns next to them
    np.testing.assert_array_equal(part[judge], full[judge])
    np.testing.assert_array_equal(part_dir[judge], full_dir[judge])
    assert not part[~judge].any()


def _brute_force_wire_points(pts: np.ndarray, radius=1.0, max_neighbours=20, max_dz=1.0, min_gap=2.5, line_radius=2.5):
    """:func:`wire_points`' definition, point by point (O(n²))."""
    x, y, z = pts.T
    plan = np.hypot(x[:, None] - x[None], y[:, None] - y[None]) <= radius
    dz = np.abs(z[:, None] - z[None])
    ok = (plan.sum(axis=1) <= max_neighbours) & ~(plan & (dz >= max_dz) & (dz < min_gap)).any(axis=1)
    p = pts - pts.mean(axis=0)
    near = np.linalg.norm(p[:, None] - p[None], axis=2) <= line_radius
    mask = np.zeros(len(pts), bool)
    for i in np.flatnonzero(ok):
        q = p[near[i]]
        ev, vec = np.linalg.eigh(np.cov(q.T, bias=True))
        axis = vec[:2, 2]
        mask[i] = len(q) >= 3 and (ev[2] - ev[1]) / max(ev[2], 1e-12) >= 0.9 and np.hypot(*axis) >= 0.9
    return mask


def test_wire_points_are_their_definition():
    """The stacked-point pre-filter and the sparse searches give the point-by-point answer, also
    with coordinates at mm (height differences of exactly 1.0 and 2.5 m) and far from the origin."""
    rng = np.random.default_rng(7)
    for off in (0.0, 4e6):
        wires = line_through(off, off, 0.4, length=40.0, rng=rng)
        crown = canopy(off + 15.0, off + 10.0, 6.0, 1_500, rng)
        # pairs straight above one another: exactly at, inside and outside the gap
        base = np.column_stack([off - 20 + rng.uniform(0, 4, 40), off - 20 + rng.uniform(0, 4, 40), np.full(40, 12.0)])
        stacks = [base + [0, 0, d] for d in (1.0, 2.5, 0.999, 1.7, 3.0)]
        pts = np.round(np.concatenate([wires, crown, base, *stacks]), 3)
        mask, _ = wire_points(pts[:, 0], pts[:, 1], pts[:, 2])
        assert mask.sum() > 50
        np.testing.assert_array_equal(mask, _brute_force_wire_points(pts))


def test_stacked_points_have_a_neighbour_in_the_gap():
    """Every point the pre-filter leaves out has a neighbour within the radius in plan and in the gap
    of heights; most points of a crown are left out."""
    from towerpipe.towers.wires import _stacked

    rng = np.random.default_rng(8)
    for off in (0.0, -1e4, 4e6):
        pts = np.round(canopy(off, off, 8.0, 3_000, rng), 2)
        x, y, z = pts.T
        got = _stacked(x, y, z, 1.0, 1.0, 2.5)
        plan = np.hypot(x[:, None] - x[None], y[:, None] - y[None]) <= 1.0
        dz = np.abs(z[:, None] - z[None])
        gap = (plan & (dz >= 1.0) & (dz < 2.5)).any(axis=1)
        assert got.mean() > 0.5
        assert not (got & ~gap).any()


def test_stacked_conductors_are_wires():
    """Conductors one above the other (a vertical circuit) are several metres apart."""
    rng = np.random.default_rng(1)
    pts = np.concatenate([conductor(X0 - 300, Y0, X0 + 300, Y0, z, rng=rng) for z in (20.0, 24.0, 28.0)])
    mask, _ = wire_points(pts[:, 0], pts[:, 1], pts[:, 2])
    assert mask.mean() > 0.8


def test_tower_on_a_line_is_supported_crane_and_passer_by_are_not():
    rng = np.random.default_rng(2)
    wires = line_through(X0, Y0, 0.7, rng=rng)
    trees = canopy(X0 + 60, Y0 - 120, 60.0, 120_000, rng)  # 10 pts/m², as a forest
    pts = np.concatenate([wires, trees])
    assert support(pts, X0, Y0) == 1.0
    # beside the line: 35 m from its axis, so the outer conductor passes 29 m away
    n = np.array([-np.sin(0.7), np.cos(0.7)])
    assert support(pts, X0 + 35 * n[0], Y0 + 35 * n[1]) <= 0.25
    # a crane: a 60 m jib at its top and nothing beyond
    jib = conductor(X0 + 1000, Y0, X0 + 1060, Y0, 40.0, sag=0.0, step=0.3, rng=rng)
    assert support(np.concatenate([pts, jib]), X0 + 1000, Y0) == 0.0


def test_terminal_tower_needs_one_side_only():
    rng = np.random.default_rng(3)
    pts = np.concatenate([conductor(X0, Y0 + a, X0 + 300, Y0 + a, 25.0, rng=rng) for a in (-5.0, 0.0, 5.0)])
    assert support(pts, X0, Y0) == 1.0


def test_no_data_in_the_ring_is_unknown_and_partial_data_is_scored_on_what_is_there():
    rng = np.random.default_rng(4)
    pts = line_through(X0, Y0, 0.0, rng=rng, length=500.0)
    assert np.isnan(support(pts, X0, Y0, extent=(X0 - 60, Y0 - 60, X0 + 60, Y0 + 60)))
    # data only east of x0 + 50: the line runs east, so the eastern sector is complete
    east = pts[pts[:, 0] > X0 + 50]
    assert support(east, X0, Y0, extent=(X0 + 50, Y0 - 300, X0 + 400, Y0 + 300)) == 1.0


def test_corridor_strip_scores_only_where_points_exist():
    # a 40 m wide strip along the line (a corridor survey): the ring beside the strip has
    # no data. Scored on the tile's box it looked like a tower without conductors
    from towerpipe.towers.coverage import Coverage

    rng = np.random.default_rng(5)
    line = line_through(X0, Y0, 0.0, rng=rng, length=400.0)
    gx, gy = np.meshgrid(np.arange(X0 - 200, X0 + 200, 2.0), np.arange(Y0 - 20, Y0 + 20, 2.0))
    cover = Coverage(np.r_[gx.ravel(), line[:, 0]], np.r_[gy.ravel(), line[:, 1]])
    box = (X0 - 200, Y0 - 200, X0 + 200, Y0 + 200)
    assert support(line, X0, Y0, extent=cover) == 1.0
    # the line crosses the strip: the sectors in the data hold no wire, but most of the ring
    # is outside the data, so where the conductors go is not known: unknown (kept, flagged)
    across = line_through(X0, Y0, np.pi / 2, rng=rng, length=400.0)
    inside = across[np.abs(across[:, 1] - Y0) < 20]
    strip = Coverage(gx.ravel(), gy.ravel())
    assert support(inside, X0, Y0, extent=strip) == 0.0
    assert np.isnan(support(inside, X0, Y0, extent=strip, min_ring_coverage=0.5))
    assert support(line, X0, Y0, extent=cover, min_ring_coverage=0.1) == 1.0
    assert support(inside, X0, Y0, extent=box) == 0.0


def test_support_is_judged_only_where_every_line_through_the_tower_shows():
    """``towers.wire_line_coverage``: a line leaves a tower in two opposite directions. At a
    zone's straight edge one of them is always in the data, so the support is judged; at its
    corner a line can leave both ways outside it (half the directions), and a tower whose
    conductors do so must not be dropped for the wires nobody surveyed."""
    from towerpipe.towers.coverage import Coverage

    rng = np.random.default_rng(7)
    # the survey: the quadrant x >= X0, y >= Y0 (a zone's corner at (X0, Y0)), with points everywhere in it
    gx, gy = np.meshgrid(np.arange(X0, X0 + 400, 5.0), np.arange(Y0, Y0 + 400, 5.0))
    survey = [(X0, Y0, X0 + 400, Y0 + 400)]

    def cover(min_line_share: float) -> Coverage:
        return Coverage(gx.ravel(), gy.ravel(), survey=survey, min_line_share=min_line_share)

    # a tower 20 m inside the corner: its line runs north-west to south-east, both ways out
    cx, cy = X0 + 20, Y0 + 20
    out = line_through(cx, cy, 3 * np.pi / 4, rng=rng, length=400.0)
    seen = out[(out[:, 0] >= X0) & (out[:, 1] >= Y0)]
    starts = np.radians(np.arange(0.0, 360.0, 5.0) + 10.0)
    rc = 80.0 + 10.0 * (np.arange(8) + 0.5)
    bx, by = cx + np.cos(starts)[:, None] * rc, cy + np.sin(starts)[:, None] * rc
    assert 0.5 < cover(1.0).lines_seen(bx, by, 4) < 0.7  # a little over half the directions show
    assert np.isnan(support(seen, cx, cy, extent=cover(1.0)))  # unknown: kept, flagged
    assert support(seen, cx, cy, extent=cover(0.0)) == 0.0  # judged anyway: dropped as a crane would be
    # the same tower with its line along the diagonal into the zone is judged and supported
    into = line_through(cx, cy, np.pi / 4, rng=rng, length=400.0)
    into = into[(into[:, 0] >= X0) & (into[:, 1] >= Y0)]
    assert np.isnan(support(into, cx, cy, extent=cover(1.0)))  # still a corner: not judged
    assert support(into, cx, cy, extent=cover(0.0)) == 1.0
    # at the zone's straight edge (200 m from the corner) every line shows through the inner half
    ex, ey = X0 + 200, Y0 + 20
    assert cover(1.0).lines_seen(ex + np.cos(starts)[:, None] * rc, ey + np.sin(starts)[:, None] * rc, 4) == 1.0
    along = line_through(ex, ey, 0.0, rng=rng, length=400.0)
    along = along[along[:, 1] >= Y0]
    assert support(along, ex, ey, extent=cover(1.0)) == 1.0
    # a crane there (nothing pointing at it) is judged: support 0, dropped
    assert support(np.empty((0, 3)), ex, ey, extent=cover(1.0)) == 0.0


def test_conductor_points_of_a_block_with_clearance(tmp_path):
    """Each wire point of the block once (tile cores), with the gap down to the vegetation below it."""
    from towerpipe.io.tiles import Tile, empty_arrays, save_tile
    from towerpipe.towers.wires import conductor_points

    rng = np.random.default_rng(5)
    wires = line_through(X0 + 250, Y0 + 250, 0.0, rng=rng, length=240.0, z0=25.0)  # west-east, sag 6 m
    trees = canopy(X0 + 250, Y0 + 250, 30.0, 20_000, rng)
    trees[:, 2] = rng.uniform(3, 12, len(trees))  # up to 12 m under it
    pts = np.concatenate([wires, trees])
    paths = []
    for k, (x0, block) in enumerate(((X0, "b"), (X0 + 250, "b"), (X0 + 500, "other"))):
        # two tiles of block b (cores x0..x0+250), each with a 40 m buffer, and a tile of another block
        inside = (pts[:, 0] >= x0 - 40) & (pts[:, 0] < x0 + 290)
        a = empty_arrays(int(inside.sum()))
        a["x"][:], a["y"][:], a["z"][:] = pts[inside, 0], pts[inside, 1], pts[inside, 2]
        a["hag"][:] = pts[inside, 2]
        a["classification"][:] = np.where(np.arange(len(pts))[inside] < len(wires), 1, 5)
        a["core"][:] = (pts[inside, 0] >= x0) & (pts[inside, 0] < x0 + 250)
        a["model_input"][:] = True
        paths.append(tmp_path / f"t{k}.npz")
        save_tile(paths[-1], Tile(a, {"block": block, "core_bounds": [x0, Y0, x0 + 250, Y0 + 500], "buffer": 40}))
    c = conductor_points([str(p) for p in paths], "b")
    is_wire = np.isin(np.round(c["x"], 6), np.round(wires[:, 0], 6))
    assert is_wire.mean() > 0.99 and len(c["x"]) > 0.8 * (wires[:, 0] < X0 + 500).sum()
    assert len(np.unique(np.c_[c["x"], c["y"]], axis=0)) == len(c["x"])  # no point twice
    assert (c["x"] < X0 + 500).all()  # not the other block's
    assert np.median(np.abs(c["direction_deg"] - 90.0)) < 2.0  # the wires run east (azimuth 90)
    over = np.hypot(c["x"] - X0 - 250, c["y"] - Y0 - 250) < 25
    assert np.isfinite(c["clearance_m"][over]).mean() > 0.9
    low = c["z"][over] - 12.0  # a conductor's height over the crowns: the clearance is at most that
    assert (c["clearance_m"][over] >= low - 1e-9).all() and (c["clearance_m"][over] < low + 2.0).mean() > 0.9
    assert np.isnan(c["clearance_m"][np.abs(c["x"] - X0 - 250) > 40]).all()  # no vegetation below


def test_conductor_points_of_a_block_are_those_its_inference_jobs_write(tmp_path):
    """Each tile's conductor points, written per tile (infer jobs) and gathered (towers job), are the block's."""
    from towerpipe.io.conductors import load_conductors, save_conductors
    from towerpipe.io.tiles import Tile, empty_arrays, load_tile, save_tile
    from towerpipe.towers.wires import CONDUCTOR_INPUT_COLUMNS, conductor_points, tile_conductor_points

    rng = np.random.default_rng(6)
    pts = np.concatenate(
        [
            line_through(X0 + 250, Y0 + 250, 0.3, rng=rng, length=400.0, z0=25.0),
            canopy(X0 + 250, Y0 + 250, 30.0, 5_000, rng),
        ]
    )
    tiles, wires = [], []
    for k, x0 in enumerate((X0, X0 + 250)):
        inside = (pts[:, 0] >= x0 - 40) & (pts[:, 0] < x0 + 290)
        a = empty_arrays(int(inside.sum()))
        a["x"][:], a["y"][:], a["z"][:], a["hag"][:] = pts[inside, 0], pts[inside, 1], pts[inside, 2], pts[inside, 2]
        a["classification"][:] = 5
        a["core"][:] = (pts[inside, 0] >= x0) & (pts[inside, 0] < x0 + 250)
        a["model_input"][:] = True
        tiles.append(str(tmp_path / f"t{k}.npz"))
        save_tile(tiles[-1], Tile(a, {"block": "b", "core_bounds": [x0, Y0, x0 + 250, Y0 + 500], "buffer": 40}))
        wires.append(str(tmp_path / "wires" / f"t{k}.npz"))
        arrays = load_tile(tiles[-1], columns=list(CONDUCTOR_INPUT_COLUMNS)).arrays
        save_conductors(wires[-1], tile_conductor_points(arrays), {"block": "b", "tile": f"t{k}"})
    block, gathered = conductor_points(tiles, "b"), load_conductors(wires)
    assert len(block["x"]) > 100
    assert block.keys() == gathered.keys()
    for k in block:
        np.testing.assert_array_equal(block[k], gathered[k])
        assert gathered[k].dtype == np.float64


def test_conductor_heights_are_those_of_the_wires_aimed_at_the_candidate():
    rng = np.random.default_rng(1)
    wires = spans(X0, Y0, 28.0, rng)
    h = conductor_heights(wires[:, 0], wires[:, 1], wires[:, 2], wires[:, 2], X0, Y0)
    # 80-160 m out of 300 m spans sagging 8 m: 8 * 4 * s * (1 - s) = 6.3-7.9 m below the top
    assert len(h) > 100
    assert 19.5 <= np.median(h) <= 22.0 and h.max() <= 28.0
    # 60 m beside the line no wire points at the candidate
    assert len(conductor_heights(wires[:, 0], wires[:, 1], wires[:, 2], wires[:, 2], X0, Y0 + 60.0)) == 0


def test_wire_support_returns_the_heights_of_the_points_it_counts():
    rng = np.random.default_rng(1)
    wires = spans(X0, Y0, 28.0, rng)
    args = (wires[:, 0], wires[:, 1], wires[:, 2], wires[:, 2], X0, Y0)
    support, h = wire_support(*args, return_heights=True)
    assert support == wire_support(*args)
    np.testing.assert_array_equal(h, conductor_heights(*args))
    # unknown support (no sector in the data): nan and no heights
    support, h = wire_support(*args, extent=(0.0, 0.0, 1.0, 1.0), return_heights=True)
    assert np.isnan(support) and len(h) == 0


def test_the_support_from_wire_points_judged_in_their_tiles(tmp_path):
    """The towers job measures a tower's support from the conductor points its tiles' jobs found
    (each judged among all the points of its own tile), not by judging the ring's points again."""
    from towerpipe.io import workdir
    from towerpipe.io.conductors import save_conductors
    from towerpipe.io.tiles import Tile, empty_arrays, load_tile, save_tile
    from towerpipe.towers.coverage import TileContext
    from towerpipe.towers.wires import CONDUCTOR_INPUT_COLUMNS, conductor_directions, tile_conductor_points

    rng = np.random.default_rng(8)
    cx, cy = X0 + 250.0, Y0 + 250.0
    pts = np.concatenate([spans(cx, cy, 28.0, rng), canopy(cx + 120.0, cy + 40.0, 25.0, 30_000, rng)])
    a = empty_arrays(len(pts))
    a["x"][:], a["y"][:], a["z"][:], a["hag"][:] = pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 2]
    a["classification"][:], a["core"][:], a["model_input"][:] = 5, True, True
    tile = tmp_path / workdir.TILE.format(block="b", tile="0_0")
    save_tile(tile, Tile(a, {"block": "b", "core_bounds": [X0 - 100, Y0 - 100, X0 + 600, Y0 + 600], "buffer": 40}))
    found = tile_conductor_points(load_tile(tile, columns=list(CONDUCTOR_INPUT_COLUMNS)).arrays)
    # the same wire points, whether read beside the tile (its inference job's file) or found here
    computed, _ = TileContext([str(tile)])(cx, cy)
    save_conductors(workdir.conductors_of(tile), found, {"block": "b", "tile": "0_0"})
    read, _ = TileContext([str(tile)])(cx, cy)
    for got in (computed["conductors"], read["conductors"]):
        np.testing.assert_array_equal(got["x"], found["x"])
        np.testing.assert_array_equal(got["direction"], conductor_directions(found["direction_deg"]))
    # what the job reads is the file, not a new search: a file of the western half gives that half
    west = {k: v[found["x"] < cx] for k, v in found.items()}
    assert 0 < len(west["x"]) < len(found["x"])
    save_conductors(workdir.conductors_of(tile), west, {"block": "b", "tile": "0_0"})
    half, _ = TileContext([str(tile)])(cx, cy)
    np.testing.assert_array_equal(half["conductors"]["x"], west["x"])
    c = read["conductors"]
    support = wire_support(c["x"], c["y"], c["z"], c["hag"], cx, cy, directions=c["direction"])
    assert support == wire_support(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 2], cx, cy) > 0.9
    # 60 m beside the line, a crown in its ring: no wire points at the candidate
    assert wire_support(c["x"], c["y"], c["z"], c["hag"], cx, cy + 60.0, directions=c["direction"]) == 0.0
    assert wire_support(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 2], cx, cy + 60.0) == 0.0


def test_conductor_directions_are_the_bearings_unit_vectors():
    u = conductor_directions(np.array([0.0, 90.0, 45.0]))
    np.testing.assert_allclose(u, [[0.0, 1.0], [1.0, 0.0], [np.sqrt(0.5), np.sqrt(0.5)]], atol=1e-12)
