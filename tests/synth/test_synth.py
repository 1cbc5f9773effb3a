"""Tests of the synthetic airborne zone generator (towerpipe.synth)."""

from __future__ import annotations

import json
from pathlib import Path

import geopandas as gpd
import laspy
import numpy as np
import pytest
import shapely

from conftest import BACKGROUNDS, TOWERS, real_tile_zone
from towerpipe.synth import Terrain, generate_zone, preset
from towerpipe.synth.scene import block_grid, block_points, build_zone

ALLOWED = {1, 2, 3, 4, 5, 6, 7, 11, 14, 15, 18}


@pytest.fixture(scope="module")
def zone(tmp_path_factory):
    out = tmp_path_factory.mktemp("zone")
    truth = generate_zone(out, seed=7, blocks=4, size=120.0, density=10.0, preset="test", edge_tower=True)
    return truth


def _read(path):
    las = laspy.read(path)
    return las


def _all_points(truth):
    lases = [_read(b["path"]) for b in truth.blocks]
    cat = {
        k: np.concatenate([np.asarray(getattr(las, k)) for las in lases])
        for k in (
            "x",
            "y",
            "z",
            "classification",
            "red",
            "nir",
            "TowerId",
            "return_number",
            "number_of_returns",
            "point_source_id",
            "intensity",
            "gps_time",
        )
    }
    return cat


def test_block_grid_is_as_square_as_possible():
    assert block_grid(4) == (2, 2)
    assert block_grid(6) == (3, 2)
    assert block_grid(1) == (1, 1)
    assert block_grid(3) == (3, 1)


def test_files_header_crs_and_roundtrip(zone):
    names = sorted(Path(b["path"]).name for b in zone.blocks)
    assert names == ["400000_4600000.laz", "400000_4600120.laz", "400120_4600000.laz", "400120_4600120.laz"]
    las = _read(zone.blocks[0]["path"])
    h = las.header
    assert (h.version.major, h.version.minor) == (1, 4) and h.point_format.id == 8
    assert h.global_encoding.wkt
    assert h.parse_crs().to_epsg() == 25831
    assert np.allclose(h.scales, 0.01)
    assert "TowerId" in las.point_format.dimension_names
    # re-generate the block in memory: the file holds the same coordinates at the LAS scale
    z = build_zone(7, blocks=4, size=120.0, density=10.0, params=preset("test", edge_tower=True))
    pts = block_points(z, 0)
    assert len(pts["x"]) == len(las.x)
    assert np.abs(np.asarray(las.x) - pts["x"]).max() <= 0.005 + 1e-9
    assert np.abs(np.asarray(las.y) - pts["y"]).max() <= 0.005 + 1e-9
    assert np.abs(np.asarray(las.z) - pts["z"]).max() <= 0.005 + 1e-9
    assert 399990 < las.x.min() and las.y.min() > 4599990


def test_determinism(tmp_path):
    a = generate_zone(tmp_path / "a", seed=3, blocks=1, size=80.0, density=8.0)
    b = generate_zone(tmp_path / "b", seed=3, blocks=1, size=80.0, density=8.0)
    c = generate_zone(tmp_path / "c", seed=4, blocks=1, size=80.0, density=8.0)
    la, lb, lc = (_read(t.blocks[0]["path"]) for t in (a, b, c))
    assert np.array_equal(la.points.array, lb.points.array)
    assert len(la.x) != len(lc.x) or not np.array_equal(np.asarray(la.z), np.asarray(lc.z))


def test_density_within_15_percent(zone):
    for b in zone.blocks:
        x0, y0, x1, y1 = b["bounds"]
        d = b["n_points"] / ((x1 - x0) * (y1 - y0))
        assert abs(d - 10.0) <= 1.5, (b["name"], d)


def test_blocks_adjoin_without_gap_or_overlap(zone):
    boxes = [shapely.box(*b["bounds"]) for b in zone.blocks]
    union = shapely.union_all(boxes)
    assert union.area == pytest.approx(sum(bx.area for bx in boxes))
    assert union.area == pytest.approx(union.envelope.area)
    for b in zone.blocks:
        las = _read(b["path"])
        x0, y0, x1, y1 = b["bounds"]
        assert las.x.min() >= x0 - 0.005 and las.x.max() <= x1 + 0.005
        assert las.y.min() >= y0 - 0.005 and las.y.max() <= y1 + 0.005
        # points reach the block edges (no gap): within 1 m of each side
        assert las.x.min() < x0 + 1 and las.x.max() > x1 - 1 and las.y.min() < y0 + 1 and las.y.max() > y1 - 1


def test_class_shares_and_returns(zone):
    p = _all_points(zone)
    cls = p["classification"]
    assert set(np.unique(cls)) <= ALLOWED
    share = {c: np.mean(cls == c) for c in ALLOWED}
    assert 0.25 < share[2] + share[11] < 0.9
    assert share[3] + share[4] + share[5] > 0.1
    assert share[15] > 0.0005 and share[14] > 0.0005 and share[1] > 0 and share[6] > 0
    assert 0 < share[7] < 0.001 and 0 < share[18] < 0.001
    assert (p["return_number"] >= 1).all() and (p["return_number"] <= p["number_of_returns"]).all()
    assert (p["number_of_returns"] > 1).mean() > 0.1  # multiple returns through canopies
    # flight strips: every point carries its strip's id (1, 2, ...), and overlapping strips sample the zone
    strips = np.unique(p["point_source_id"])
    assert strips.min() >= 1 and len(strips) >= 2


def test_ground_lies_on_true_terrain_and_noise_is_off_it(zone):
    t = Terrain.load(zone.out_dir / "terrain.npz")
    p = _all_points(zone)
    hag = p["z"] - t.z(p["x"], p["y"])
    g = p["classification"] == 2
    assert np.abs(hag[g]).max() < 0.05
    assert (hag[p["classification"] == 7] < -0.5).all()
    assert (hag[p["classification"] == 18] > 15).all()
    assert hag[p["classification"] == 5].min() >= 7.9


def test_towers_match_truth(zone):
    gpkg = gpd.read_file(zone.out_dir / "towers_truth.gpkg", layer="towers")
    gj = gpd.read_file(zone.out_dir / "towers_truth.geojson")
    assert len(gpkg) == len(gj) == len(zone.towers) >= 2
    assert gpkg["tower_id"].is_unique
    p = _all_points(zone)
    tid = p["TowerId"]
    assert (tid[p["classification"] == 15] > 0).all() and (tid[p["classification"] != 15] == 0).all()
    ids, counts = np.unique(tid[tid > 0], return_counts=True)
    assert set(ids.tolist()) <= set(gpkg["tower_id"].tolist())
    t = Terrain.load(zone.out_dir / "terrain.npz")
    for row in gpkg.itertuples():
        assert 10.0 <= row.height <= 50.0
        sel = tid == row.tower_id
        assert sel.sum() == row.n_points
        if row.n_points < 20:
            continue
        inside = shapely.contains_xy(row.geometry.buffer(0.6), p["x"][sel], p["y"][sel])
        assert inside.all()
        top = p["z"][sel].max() - row.base_z
        assert row.height - 4.0 <= top <= row.height + 1.0
        assert abs(row.base_z - t.z(np.array([row.x]), np.array([row.y]))[0]) < 0.01
    # one tower straddles an inner block edge
    assert (gpkg["blocks"].str.count(",") >= 1).any()
    assert set(gpkg["design"]) <= {"lattice_waist", "double_circuit", "small_lattice", "monopole"}


def test_wires_connect_consecutive_towers(zone):
    gpkg = gpd.read_file(zone.out_dir / "towers_truth.gpkg", layer="towers").set_index("tower_id")
    spans = np.asarray(zone.spans)
    assert len(spans) >= 1
    p = _all_points(zone)
    w = p["classification"] == 14
    wx, wy = p["x"][w], p["y"][w]
    for a, b in spans:
        ax, ay, bx, by = gpkg.loc[a, "x"], gpkg.loc[a, "y"], gpkg.loc[b, "x"], gpkg.loc[b, "y"]
        d = np.array([bx - ax, by - ay])
        L = np.hypot(*d)
        t = ((wx - ax) * d[0] + (wy - ay) * d[1]) / L**2
        off = np.abs((wx - ax) * d[1] - (wy - ay) * d[0]) / L
        near = (t > 0.1) & (t < 0.9) & (off < 14.0)
        # wire points all along the span (every fifth of it)
        bins = np.unique(np.floor(t[near] * 5))
        assert len(bins) >= 4, (a, b, near.sum())


def test_ndvi_separates_vegetation_from_steel(zone):
    p = _all_points(zone)
    red = p["red"].astype(float)
    nir = p["nir"].astype(float)
    ndvi = (nir - red) / np.maximum(nir + red, 1)
    veg = ndvi[p["classification"] == 5]
    steel = ndvi[p["classification"] == 15]
    roofs = ndvi[p["classification"] == 6]
    assert np.median(veg) > 0.4
    assert np.median(steel) < 0.2 and np.median(roofs) < 0.15
    assert np.median(veg) - np.median(steel) > 0.3
    assert (p["red"] % 257 == 0).all()


def test_catalonia_share_of_medium_vegetation(tmp_path):
    t = generate_zone(tmp_path, seed=11, blocks=1, size=200.0, density=6.0)
    las = _read(t.blocks[0]["path"])
    terrain = Terrain.load(tmp_path / "terrain.npz")
    cls = np.asarray(las.classification)
    hag = np.asarray(las.z) - terrain.z(np.asarray(las.x), np.asarray(las.y))
    ng = ~np.isin(cls, [2, 11, 7, 18])
    share = np.mean((hag[ng] >= 3) & (hag[ng] < 8))
    assert 0.35 < share < 0.8, share
    meta = json.loads((tmp_path / "synth_meta.json").read_text())
    assert meta["seed"] == 11 and meta["params"]["forest_cover"] > 0


def test_scan_pattern_not_uniform(zone):
    las = _read(zone.blocks[0]["path"])
    ang = np.asarray(las.scan_angle) * 0.006
    assert np.abs(ang).max() <= 20.5
    # zig-zag lines: GPS times of consecutive ground returns advance monotonically within a strip
    g = (np.asarray(las.classification) == 2) & (np.asarray(las.return_number) == np.asarray(las.number_of_returns))
    t = np.asarray(las.gps_time)[g]
    src = np.asarray(las.point_source_id)[g]
    same = src[1:] == src[:-1]
    assert (np.diff(t)[same] >= 0).mean() > 0.99


def test_cli_synth(tmp_path):
    from towerpipe.cli import main

    rc = main(
        [
            "synth",
            "--seed",
            "5",
            "--blocks",
            "2",
            "--size",
            "80",
            "--density",
            "6",
            "--out",
            str(tmp_path / "z"),
            "--edge-tower",
        ]
    )
    assert rc == 0
    files = sorted(p.name for p in (tmp_path / "z").glob("*.laz"))
    assert files == ["400000_4600000.laz", "400080_4600000.laz"]
    gdf = gpd.read_file(tmp_path / "z" / "towers_truth.gpkg", layer="towers")
    assert len(gdf) >= 1 and (gdf["blocks"].str.contains(",")).any()


def test_tower_points_per_tower_range(tmp_path):
    t = generate_zone(
        tmp_path,
        seed=2,
        blocks=1,
        size=300.0,
        density=10.0,
        preset="test",
        roads=0.0,
        villages=0.0,
        forest_cover=0.0,
        shrub_density=0.0,
    )
    n = t.towers["n_points"].to_numpy()
    assert len(n) >= 2
    assert n.min() >= 10 and n.max() <= 3000


def test_utility_poles_only_where_named(tmp_path):
    """``utility_pole`` is drawn only by a zone that names it: single thin poles of 14-30 m
    carrying conductors; the default and ``tower_variety`` designs never include it."""
    from towerpipe.synth.params import TOWER_VARIETY
    from towerpipe.synth.towers import DESIGNS, UTILITY

    assert not set(UTILITY) & (set(DESIGNS) | set(TOWER_VARIETY["designs"]) | set(preset("catalonia").designs))
    t = generate_zone(
        tmp_path, seed=5, blocks=1, size=300.0, density=12.0, preset="test", lines_per_km2=20.0,
        tower_variety=True, designs=["utility_pole"], design_weights=[1.0],
    )  # fmt: skip
    towers = t.towers
    assert len(towers) >= 3 and set(towers["design"]) == {"utility_pole"}
    assert towers["height"].between(14.0, 30.0).all()
    assert (towers["base_width"] <= 0.55).all()
    p = _all_points(t)
    for row in towers[towers["n_points"] >= 20].itertuples():
        sel = p["TowerId"] == row.tower_id
        # a pole and its arms: the points spread at most an arm's length (2.4 m) from the axis
        r = np.hypot(p["x"][sel] - row.x, p["y"][sel] - row.y)
        assert r.max() <= 2.7
    assert (p["classification"] == 14).sum() > 0  # the conductors between them


def test_headed_lattices_only_where_named(tmp_path):
    """``cat_head`` and ``wine_glass`` are drawn only by a zone that names them: lattices whose
    head, above a narrow waist, spreads wider than the body below it."""
    from towerpipe.synth.params import TOWER_VARIETY
    from towerpipe.synth.towers import DESIGNS, HEADED, HEIGHTS

    assert not set(HEADED) & (set(DESIGNS) | set(TOWER_VARIETY["designs"]) | set(preset("catalonia").designs))
    t = generate_zone(
        tmp_path, seed=6, blocks=1, size=300.0, density=12.0, preset="test", lines_per_km2=20.0,
        tower_variety=True, designs=list(HEADED), design_weights=[0.5, 0.5],
    )  # fmt: skip
    towers = t.towers
    heads = towers[towers["design"].isin(HEADED)]
    assert len(heads) >= 3 and set(towers["design"]) <= set(HEADED) | {"lattice_waist", "double_circuit"}
    for row in heads.itertuples():
        assert HEIGHTS[row.design][0] - 0.01 <= row.height <= HEIGHTS[row.design][1] + 0.01
    p = _all_points(t)
    for row in heads[heads["n_points"] >= 100].itertuples():
        sel = p["TowerId"] == row.tower_id
        r = np.hypot(p["x"][sel] - row.x, p["y"][sel] - row.y)
        rel = (p["z"][sel] - p["z"][sel].min()) / row.height
        bands = [r[(rel >= lo) & (rel < lo + 0.1)] for lo in np.arange(0.3, 0.6, 0.05)]
        waist = min(np.percentile(b, 90) for b in bands if len(b) >= 5)
        assert np.percentile(r[rel > 0.72], 90) > 1.5 * waist


def test_realism_report(zone, tmp_path):
    from towerpipe.cli import main

    rc = main(["synth-report", "--zone", str(zone.out_dir), "--out", str(tmp_path / "rep")])
    assert rc == 0
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "points per tower" in md
    stats = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert stats["n_towers"] == int((zone.towers["n_points"] > 0).sum())
    assert stats["median_points_per_tower"] == pytest.approx(
        float(np.median(zone.towers["n_points"][zone.towers["n_points"] > 0]))
    )
    assert (tmp_path / "rep" / "hag_cdf.png").stat().st_size > 10_000


@pytest.mark.shared
def test_real_towers_inserted(tmp_path):
    t = generate_zone(
        tmp_path, seed=1, blocks=2, size=150.0, density=10.0, preset="test", tower_source="real", real_towers=TOWERS
    )
    assert len(t.towers) >= 1 and t.towers["design"].str.startswith("real:").all()
    p = _all_points(t)
    assert (p["classification"] == 15).sum() == t.towers["n_points"].sum()
    assert t.towers["height"].between(10, 50).all()


@pytest.mark.shared
def test_real_backgrounds_keep_crs_and_get_towers(tmp_path):
    bg = BACKGROUNDS
    t = generate_zone(tmp_path, seed=2, real_backgrounds=bg)
    assert len(t.blocks) == len(list(bg.glob("*.laz")))
    las = laspy.read(t.blocks[0]["path"])
    assert las.header.parse_crs().to_epsg() == 2154 and las.header.point_format.id == 8
    p = _all_points(t)
    assert (p["TowerId"] > 0).sum() == t.towers["n_points"].sum() > 0
    assert (p["nir"] > 0).mean() > 0.9  # synthetic NIR where the tile has none


@pytest.mark.shared
def test_realshape_zone_families_lines_and_variants(tmp_path):
    """A benchmark zone: one real family on a real tile, towers on lines carrying conductors, on data;
    the degraded variants share the geometry and lose only their attributes."""
    from towerpipe.synth.real import tower_family

    kw = real_tile_zone(5, "ts40k", (4, 15), tower_variety=True)
    t = generate_zone(tmp_path / "intact", **kw)
    assert len(t.blocks) == 1 and len(t.towers) >= 3
    assert {tower_family(d) for d in t.towers["design"]} == {"ts40k"}
    assert t.towers["height"].between(10, 60).all()
    p = _all_points(t)
    assert (p["TowerId"] > 0).sum() == t.towers["n_points"].sum()
    # every tower stands on ground the tile has data of, and carries conductors
    ground = p["classification"] == 2
    gtree = shapely.STRtree(shapely.points(p["x"][ground][::20], p["y"][ground][::20]))
    wires = shapely.points(p["x"][p["classification"] == 14], p["y"][p["classification"] == 14])
    for _, r in t.towers.iterrows():
        base = shapely.Point(r["x"], r["y"])
        assert gtree.query(base, predicate="dwithin", distance=6.0).size > 0
        assert shapely.dwithin(wires, base, 15.0).sum() > 20
    # towers are coloured mostly by the orthophoto below them, not by a steel signature
    own = p["classification"] == 15
    assert abs(np.median(p["red"][own]) - np.median(p["red"][ground])) < 0.25 * 65535
    bare = generate_zone(tmp_path / "bare", **kw, variant="no_intensity")
    q = _all_points(bare)
    np.testing.assert_array_equal(q["x"], p["x"])
    assert not q["intensity"].any() and not q["return_number"].any() and not q["gps_time"].any()
    nocol = generate_zone(tmp_path / "nocol", **kw, variant="no_colour")
    las = laspy.read(nocol.blocks[0]["path"])
    assert las.header.point_format.id == 6 and "red" not in las.point_format.dimension_names


@pytest.mark.shared
def test_realshape_zone_tower_height_scales_the_real_shapes(tmp_path):
    """``tower_height`` scales every real shape to a height drawn from its range (a zone of small
    UAV lattices, whose sources are 17-58 m tall); without it the shapes keep their own heights."""
    kw = real_tile_zone(9, "uav", (4, 7))
    small = generate_zone(tmp_path / "small", **kw, tower_height=(14, 19))
    own = generate_zone(tmp_path / "own", **kw)
    assert len(small.towers) >= 3
    assert small.towers["height"].between(14, 19).all()
    assert own.towers["height"].max() > 19
    pts = _all_points(small)
    for _, r in small.towers.iterrows():
        z = pts["z"][pts["TowerId"] == r["tower_id"]]
        assert z.max() - r["base_z"] <= r["height"] + 0.5


def _assert_cranes_beside_lines(p, cranes):
    """Each crane stands 20-55 m high on a mast of class 1 points with no tower id (from the ground
    up to the jib), beside a line: its conductors pass within the cranes' range across it."""
    from towerpipe.synth.negatives import BESIDE_LINE_ACROSS_M

    wires = p["classification"] == 14
    wx, wy = p["x"][wires], p["y"][wires]
    for n in cranes:
        assert 20.0 <= n["height"] <= 55.0
        mast = (np.hypot(p["x"] - n["x"], p["y"] - n["y"]) < 1.5) & (p["classification"] == 1)
        assert mast.sum() > 20 and not p["TowerId"][mast].any()
        assert float(np.hypot(wx - n["x"], wy - n["y"]).min()) < BESIDE_LINE_ACROSS_M[1] + 2.0


@pytest.mark.shared
def test_cranes_beside_lines_on_real_backgrounds(tmp_path):
    """``cranes_beside_lines`` stands tower cranes (class 1, no tower id) 12-40 m across a line of the
    tile, records them in the metadata, and leaves a zone without them as it was."""
    from towerpipe.synth.truth import META_JSON

    kw = real_tile_zone(11, "uav", (10, 20))
    plain = generate_zone(tmp_path / "plain", **kw)
    none = generate_zone(tmp_path / "none", **kw, cranes_beside_lines=0)
    np.testing.assert_array_equal(_all_points(none)["x"], _all_points(plain)["x"])
    assert json.loads((tmp_path / "none" / META_JSON).read_text())["negatives"] == []

    t = generate_zone(tmp_path / "cranes", **kw, cranes_beside_lines=3)
    negs = t.meta["negatives"]
    assert len(negs) == 3 and {n["kind"] for n in negs} == {"crane"}
    assert json.loads((tmp_path / "cranes" / META_JSON).read_text())["negatives"] == negs
    _assert_cranes_beside_lines(_all_points(t), negs)
    # the towers are those of the zone without cranes
    assert t.towers["design"].tolist() == plain.towers["design"].tolist()


def test_cranes_beside_lines_on_generated_zones(tmp_path):
    """On a generated zone ``cranes_beside_lines`` stands that many tower cranes in each block that
    holds a line tower, beside one of its towers, and changes nothing else of the zone."""

    kw = dict(seed=5, blocks=2, size=300, density=4, preset="catalonia", lines_per_km2=8.0)
    plain = generate_zone(tmp_path / "plain", **kw)
    t = generate_zone(tmp_path / "cranes", **kw, cranes_beside_lines=2)
    cranes = [n for n in t.meta["negatives"] if n["kind"] == "crane"]
    others = [n for n in t.meta["negatives"] if n["kind"] != "crane"]
    assert others == plain.meta["negatives"]
    bounds = [b["bounds"] for b in t.meta["blocks"]]
    with_towers = [
        b for b in bounds if any(b[0] <= x < b[2] and b[1] <= y < b[3] for x, y in zip(t.towers["x"], t.towers["y"]))
    ]
    assert len(cranes) == 2 * len(with_towers) > 0
    _assert_cranes_beside_lines(_all_points(t), cranes)
    assert t.towers["design"].tolist() == plain.towers["design"].tolist()
    assert (t.towers["n_points"] == plain.towers["n_points"]).all()
