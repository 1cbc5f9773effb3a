"""Tests of towerpipe.gpkg: the tower GeoPackage and the zone merge."""

from __future__ import annotations

import sqlite3
import xml.etree.ElementTree as ET

import numpy as np
import pyogrio
import pytest
import shapely
from pyproj import CRS as ProjCRS

from towerpipe import __version__
from towerpipe.errors import InputError
from towerpipe.gpkg import (
    LAYER_POINTS,
    LAYER_TOWERS,
    config_hash,
    default_style,
    merge_gpkgs,
    read_metadata,
    read_towers,
    run_metadata,
    write_towers_gpkg,
)
from towerpipe.towers import TOWER_COLUMNS, empty_towers, extract_towers

X0, Y0 = 400_000.0, 4_600_000.0
WKT = ProjCRS.from_epsg(25831).to_wkt()
MODEL = {"name": "pointnet_l", "version": "1.2.0", "sha256": "ab" * 32}


def tower_points(cx: float, cy: float, height: float = 30.0, step: float = 0.5) -> np.ndarray:
    """Four converging legs of a tower, base at z = 100."""
    t = np.arange(0.0, height, step)
    half = 3.0 - 2.0 * t / height
    return np.concatenate([np.column_stack([cx + sx * half, cy + sy * half, 100.0 + t])
                           for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1))])


def towers_for(block: str, bounds: tuple[float, float, float, float], centres: list[tuple[float, float]]):
    xyz = np.concatenate([tower_points(cx, cy) for cx, cy in centres])
    n = len(xyz)
    arrays = {"block_id": np.zeros(n, np.int32), "point_index": np.arange(n, dtype=np.int64),
              "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": (xyz[:, 2] - 100).astype(np.float32),
              "prob": np.full(n, 0.9, np.float32)}
    meta = {"blocks": [block], "crs_wkt": WKT, "model": MODEL}
    return extract_towers([(arrays, meta)], block, bounds, zone="z1", source_files={block: f"/in/{block}.laz"},
                          processed_at="2024-05-01T12:00:00+00:00")


@pytest.fixture
def two_towers():
    return towers_for("b1", (X0, Y0, X0 + 500, Y0 + 500), [(X0 + 50, Y0 + 50), (X0 + 300, Y0 + 120)])


def test_write_read_schema_crs_metadata(tmp_path, two_towers):
    md = run_metadata(model_meta=MODEL, config={"threshold": 0.5}, run_time="2024-05-01T12:00:00+00:00",
                      zone="z1", block="b1")
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
        for c in ("f_table_catalog", "f_table_schema", "f_table_name", "f_geometry_column", "styleName",
                  "styleQML", "styleSLD", "useAsDefault", "update_time"):
            assert c in cols
        rows = con.execute("SELECT f_table_name, f_geometry_column, f_table_schema, useAsDefault, styleQML "
                           "FROM layer_styles ORDER BY f_table_name").fetchall()
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
    path = write_towers_gpkg(tmp_path / "empty.gpkg", empty_towers(), crs_wkt=WKT,
                             metadata=run_metadata(model_meta=MODEL))
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
