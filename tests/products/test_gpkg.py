"""Tests of towerpipe.products.gpkg and gpkg_read: the tower GeoPackage and the zone merge."""

from __future__ import annotations

import sqlite3
import xml.etree.ElementTree as ET

import numpy as np
import pyogrio
import pytest
import shapely
from pyproj import CRS as ProjCRS

from conftest import extract
from towerpipe import __version__
from towerpipe.errors import InputError
from towerpipe.model.cards import config_hash
from towerpipe.products.gpkg import (
    LAYER_POINTS,
    LAYER_TOWERS,
    default_style,
    run_metadata,
    write_towers_gpkg,
)
from towerpipe.products.gpkg_read import merge_gpkgs, read_metadata, read_towers
from towerpipe.towers.records import TOWER_COLUMNS, empty_towers

X0, Y0 = 400_000.0, 4_600_000.0
WKT = ProjCRS.from_epsg(25831).to_wkt()
MODEL = {"name": "pointnet_l", "version": "1.2.0", "sha256": "ab" * 32}


def tower_points(cx: float, cy: float, height: float = 30.0, step: float = 0.5) -> np.ndarray:
    """Four converging legs of a tower, base at z = 100."""
    t = np.arange(0.0, height, step)
    half = 3.0 - 2.0 * t / height
    return np.concatenate(
        [
            np.column_stack([cx + sx * half, cy + sy * half, 100.0 + t])
            for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1))
        ]
    )


def towers_for(block: str, bounds: tuple[float, float, float, float], centres: list[tuple[float, float]]):
    xyz = np.concatenate([tower_points(cx, cy) for cx, cy in centres])
    n = len(xyz)
    arrays = {
        "block_id": np.zeros(n, np.int32),
        "point_index": np.arange(n, dtype=np.int64),
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
        "hag": (xyz[:, 2] - 100).astype(np.float32),
        "prob": np.full(n, 0.9, np.float32),
    }
    meta = {"blocks": [block], "crs_wkt": WKT, "model": MODEL}
    return extract(
        [(arrays, meta)],
        block,
        bounds,
        zone="z1",
        source_files={block: f"/in/{block}.laz"},
        processed_at="2024-05-01T12:00:00+00:00",
    ).towers


@pytest.fixture
def two_towers():
    return towers_for("b1", (X0, Y0, X0 + 500, Y0 + 500), [(X0 + 50, Y0 + 50), (X0 + 300, Y0 + 120)])


def test_write_read_schema_crs_metadata(tmp_path, two_towers):
    md = run_metadata(
        model_meta=MODEL, config={"threshold": 0.5}, run_time="2024-05-01T12:00:00+00:00", zone="z1", block="b1"
    )
    path = write_towers_gpkg(tmp_path / "towers.gpkg", two_towers, crs_wkt=WKT, metadata=md)
    layers = dict(pyogrio.list_layers(path))
    assert layers[LAYER_TOWERS] == "Polygon" and layers[LAYER_POINTS] == "Point"
    assert "layer_styles" in layers
    polys = read_towers(path)
    pts = read_towers(path, LAYER_POINTS)
    for gdf in (polys, pts):
        assert list(gdf.columns) == list(TOWER_COLUMNS) + ["geometry"]
        assert gdf.crs.to_epsg() == 25831
        assert gdf.geometry.is_valid.all()
        assert list(gdf["tower_id"]) == list(two_towers["tower_id"])
    info = pyogrio.read_info(path, layer=LAYER_TOWERS)
    assert info["ogr_types"][list(info["fields"]).index("n_points")] == "OFTInteger64"
    assert info["ogr_types"][list(info["fields"]).index("height_m")] == "OFTReal"
    np.testing.assert_allclose(pts.geometry.x, polys["centroid_x"])
    np.testing.assert_allclose(pts.geometry.y, polys["centroid_y"])
    assert polys.geometry.iloc[0].equals_exact(two_towers.geometry.iloc[0], 1e-6)
    meta = read_metadata(path)
    assert meta["towerpipe_version"] == __version__
    assert meta["model_version"] == "1.2.0" and meta["config_hash"] == config_hash({"threshold": 0.5})
    assert meta["run_time"] == "2024-05-01T12:00:00+00:00" and meta["n_towers"] == "2"
    with sqlite3.connect(path) as con:  # standard GeoPackage metadata tables
        scopes = {r[0] for r in con.execute("SELECT reference_scope FROM gpkg_metadata_reference")}
        assert "geopackage" in scopes
        assert "config_hash" in con.execute("SELECT group_concat(metadata) FROM gpkg_metadata").fetchone()[0]
    assert not list(tmp_path.glob(".*part*"))


def test_embedded_qgis_style(tmp_path, two_towers):
    path = write_towers_gpkg(tmp_path / "t.gpkg", two_towers)
    with sqlite3.connect(path) as con:
        cols = [r[1] for r in con.execute("PRAGMA table_info(layer_styles)")]
        for c in (
            "f_table_catalog",
            "f_table_schema",
            "f_table_name",
            "f_geometry_column",
            "styleName",
            "styleQML",
            "styleSLD",
            "useAsDefault",
            "update_time",
        ):
            assert c in cols
        rows = con.execute(
            "SELECT f_table_name, f_geometry_column, f_table_schema, useAsDefault, styleQML "
            "FROM layer_styles ORDER BY f_table_name"
        ).fetchall()
        geom_col = con.execute("SELECT column_name FROM gpkg_geometry_columns WHERE table_name='towers'").fetchone()[0]
    assert [r[0] for r in rows] == [LAYER_POINTS, LAYER_TOWERS]
    for name, gcol, schema, default, qml in rows:
        assert gcol == geom_col and schema == "" and default == 1
        root = ET.fromstring(qml)
        assert root.tag == "qgis"
        symbol = root.find("renderer-v2/symbols/symbol")
        assert symbol.get("type") == ("marker" if name == LAYER_POINTS else "fill")
        aliased = {a.get("field") for a in root.iter("alias")}
        assert set(TOWER_COLUMNS) <= aliased
    assert default_style("polygon") != default_style("point")


def test_empty_block(tmp_path):
    path = write_towers_gpkg(
        tmp_path / "empty.gpkg", empty_towers(), crs_wkt=WKT, metadata=run_metadata(model_meta=MODEL)
    )
    for layer, gtype in ((LAYER_TOWERS, "Polygon"), (LAYER_POINTS, "Point")):
        info = pyogrio.read_info(path, layer=layer)
        assert info["features"] == 0 and info["geometry_type"] == gtype
        assert list(info["fields"]) == list(TOWER_COLUMNS)
        gdf = read_towers(path, layer)
        assert len(gdf) == 0 and gdf.crs.to_epsg() == 25831
    assert read_metadata(path)["n_towers"] == "0"
    write_towers_gpkg(tmp_path / "none.gpkg", None, crs_wkt=WKT)
    assert len(read_towers(tmp_path / "none.gpkg")) == 0
    with pytest.raises(ValueError):
        write_towers_gpkg(tmp_path / "nocrs.gpkg", None)


def test_overwrite_is_atomic_replace(tmp_path, two_towers):
    path = tmp_path / "t.gpkg"
    write_towers_gpkg(path, two_towers)
    write_towers_gpkg(path, two_towers.iloc[:1])
    assert len(read_towers(path)) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.gpkg"]


def test_merge_blocks(tmp_path):
    west = towers_for("bw", (X0, Y0, X0 + 250, Y0 + 500), [(X0 + 50, Y0 + 50)])
    east = towers_for("be", (X0 + 250, Y0, X0 + 500, Y0 + 500), [(X0 + 300, Y0 + 50), (X0 + 400, Y0 + 400)])
    pw = write_towers_gpkg(tmp_path / "bw.gpkg", west, metadata=run_metadata(model_meta=MODEL, block="bw"))
    pe = write_towers_gpkg(tmp_path / "be.gpkg", east, metadata=run_metadata(model_meta=MODEL, block="be"))
    pn = write_towers_gpkg(tmp_path / "bn.gpkg", None, crs_wkt=WKT, metadata=run_metadata(model_meta=MODEL))
    out = merge_gpkgs([pw, pe, pn], tmp_path / "zone" / "towers.gpkg")
    merged = read_towers(out)
    assert len(merged) == 3 and merged["tower_id"].is_unique
    assert set(merged["block"]) == {"bw", "be"}
    assert merged.crs.to_epsg() == 25831
    assert len(read_towers(out, LAYER_POINTS)) == 3
    md = read_metadata(out)
    assert md["blocks"] == "3" and md["n_towers"] == "3" and "block" not in md
    assert md["model_version"] == "1.2.0"
    # the same block given twice: ids stay unique
    again = read_towers(merge_gpkgs([pw, pw, pe], tmp_path / "dup.gpkg"))
    assert len(again) == 3 and again["tower_id"].is_unique


def test_merge_empty_and_mismatched_crs(tmp_path, two_towers):
    out = merge_gpkgs([], tmp_path / "e.gpkg", crs_wkt=WKT)
    assert len(read_towers(out)) == 0
    other = two_towers.to_crs(3857)
    a = write_towers_gpkg(tmp_path / "a.gpkg", two_towers)
    b = write_towers_gpkg(tmp_path / "b.gpkg", other)
    with pytest.raises(InputError):
        merge_gpkgs([a, b], tmp_path / "m.gpkg")
    with pytest.raises(InputError):
        read_towers(tmp_path / "missing.gpkg")


def test_geometry_roundtrip_exact(tmp_path):
    t = towers_for("b", (X0, Y0, X0 + 500, Y0 + 500), [(X0 + 10.25, Y0 + 20.75)])
    path = write_towers_gpkg(tmp_path / "t.gpkg", t)
    back = read_towers(path)
    assert shapely.equals_exact(back.geometry.iloc[0], t.geometry.iloc[0], 1e-9)
    assert back["n_points"].dtype == np.int64 and back["height_m"].iloc[0] == t["height_m"].iloc[0]


# --------------------------------------------------------------------------- hygiene
def zone_file(tmp_path):
    """A zone-like GeoPackage with every layer: towers, lines, spans, vanished towers."""
    from towerpipe.products.registry_file import read_registry
    from towerpipe.towers.lines import build_lines
    from towerpipe.towers.registry import update_registry, vanished

    towers = towers_for("b1", (X0, Y0, X0 + 500, Y0 + 500), [(X0 + 50, Y0 + 50), (X0 + 350, Y0 + 50)])
    u = np.linspace(0, 300, 600)
    cond = {
        "x": np.r_[X0 + 50 + u, X0 + 50 + u],
        "y": np.r_[np.full(600, Y0 + 47), np.full(600, Y0 + 53)],
        "hag": np.full(1200, 14.0),
        "direction_deg": np.full(1200, 90.0),
        "clearance_m": np.full(1200, 7.5),
    }
    towers, lines, spans = build_lines(towers, cond)
    gone = towers_for("b1", (X0, Y0, X0 + 500, Y0 + 500), [(X0 + 200, Y0 + 300)])
    reg = update_registry(read_registry(), gone, run_time="2024-04-01T00:00:00Z")
    reg = update_registry(reg, towers, run_time="2024-05-01T00:00:00Z")
    path = write_towers_gpkg(
        tmp_path / "towers.gpkg",
        towers,
        lines=lines,
        spans=spans,
        vanished=vanished(reg),
        metadata=run_metadata(model_meta=dict(MODEL, choice={"mode": "auto", "reason": "rgb"})),
    )
    return path, towers, lines, spans


def test_geopackage_version_and_fields(tmp_path):
    """GeoPackage 1.2, DATETIME fields, values to the cm, height = top - base, descriptions with units."""
    from towerpipe.towers.lines import LINE_FIELDS, SPAN_FIELDS
    from towerpipe.towers.records import TOWER_FIELDS
    from towerpipe.towers.registry import REGISTRY_FIELDS

    path, towers, lines, spans = zone_file(tmp_path)
    assert dict(pyogrio.list_layers(path)) == {
        "towers": "Polygon",
        "tower_points": "Point",
        "lines": "LineString",
        "spans": "LineString",
        "vanished_towers": "Polygon",
        "layer_styles": None,
    }
    with sqlite3.connect(path) as con:
        assert con.execute("PRAGMA user_version").fetchone()[0] == 10200 < 10400
        types = {r[1]: r[2] for r in con.execute("PRAGMA table_info(towers)")}
        assert types["processed_at"] == types["first_seen"] == "DATETIME" and types["tower_id"] == "INTEGER"
        stamp = con.execute("SELECT processed_at FROM towers").fetchone()[0]
        assert stamp == "2024-05-01T12:00:00.000Z"
        rows = con.execute("SELECT height_m, top_z, base_z, centroid_x, footprint_area_m2, prob_mean FROM towers")
        for height, top, base, cx, area, prob in rows:
            assert height == pytest.approx(top - base, abs=0.005)
            for v in (height, top, base, cx, area):
                assert v == round(v, 2)
            assert prob == round(prob, 3)
        cols = {
            (t, c): (title, desc, cname)
            for t, c, title, desc, cname in con.execute(
                "SELECT table_name, column_name, title, description, constraint_name FROM gpkg_data_columns"
            )
        }
        enum = [
            r[0]
            for r in con.execute(
                "SELECT value FROM gpkg_data_column_constraints "
                "WHERE constraint_name = 'review_status_values' ORDER BY value"
            )
        ]
        ext = con.execute("SELECT count(*) FROM gpkg_extensions WHERE extension_name = 'gpkg_schema'").fetchone()[0]
    for table, fields in (
        ("towers", TOWER_FIELDS),
        ("tower_points", TOWER_FIELDS),
        ("lines", LINE_FIELDS),
        ("spans", SPAN_FIELDS),
        ("vanished_towers", REGISTRY_FIELDS),
    ):
        for name, f in fields.items():
            assert cols[(table, name)][:2] == (f.title, f.description)
    assert cols[("towers", "height_m")][0] == "Height (m)" and "(m)" in cols[("towers", "top_z")][1]
    assert cols[("towers", "review_status")][2] == "review_status_values"
    assert enum == ["confirmed", "rejected", "unreviewed"] and ext == 2
    back = read_towers(path)
    assert set(back["review_status"]) == {"unreviewed"}
    assert back["line_id"].dtype.kind == "i" and (back["line_id"] == lines["line_id"].iloc[0]).all()
    assert read_metadata(path)["model_choice"] == '{"mode": "auto", "reason": "rgb"}'
    assert len(read_towers(path, "vanished_towers")) == 1 and len(read_towers(path, "spans")) == 1


def test_gdal36_opens_without_warning_and_validates(tmp_path, gdal36):
    """What QGIS LTR on Debian 12 sees: no warning, and GDAL's validator (Req 75: the R-tree
    triggers of GeoPackage 1.2) passes. A GeoPackage 1.4 file, GDAL's default since 3.7, fails both."""
    path, *_ = zone_file(tmp_path)
    block = write_towers_gpkg(
        tmp_path / "block.gpkg", towers_for("b", (X0, Y0, X0 + 500, Y0 + 500), [(X0 + 50, Y0 + 50)])
    )
    for p in (path, block):
        info = gdal36("ogrinfo", "-so", "-al", str(p))
        assert info.returncode == 0 and "3.6" not in info.stderr and info.stderr.strip() == "", info.stderr
        assert "Layer name: towers" in info.stdout
        check = gdal36("validate_gpkg", "-k", str(p))
        assert check.returncode == 0, check.stdout + check.stderr
    newer = tmp_path / "v14.gpkg"
    towers_for("b", (X0, Y0, X0 + 500, Y0 + 500), [(X0 + 50, Y0 + 50)]).to_file(newer, engine="pyogrio")
    assert "user_version=0x000028A0" in gdal36("ogrinfo", "-so", str(newer)).stderr
    assert "Req 75" in gdal36("validate_gpkg", "-k", str(newer)).stdout


def test_every_layer_has_its_qgis_style(tmp_path):
    path, *_ = zone_file(tmp_path)
    with sqlite3.connect(path) as con:
        rows = dict(con.execute("SELECT f_table_name, styleQML FROM layer_styles WHERE useAsDefault = 1"))
    kinds = {
        "towers": ("fill", 2),
        "tower_points": ("marker", 0),
        "lines": ("line", 1),
        "spans": ("line", 1),
        "vanished_towers": ("fill", 2),
    }
    assert set(rows) == set(kinds)
    for layer, (kind, gtype) in kinds.items():
        root = ET.fromstring(rows[layer].split("\n", 1)[1])
        assert root.find("renderer-v2/symbols/symbol").get("type") == kind
        assert root.find("layerGeometryType").text == str(gtype)
        fields = [c for c in pyogrio.read_info(path, layer=layer)["fields"]]
        aliases = {a.get("field"): a.get("name") for a in root.iter("alias")}
        assert set(fields) <= set(aliases) and all(aliases[f] for f in fields)
