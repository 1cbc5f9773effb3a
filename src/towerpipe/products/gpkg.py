"""The tower GeoPackage: per-block ``towers/<block>.gpkg`` and the zone's ``towers.gpkg``.

A tower GeoPackage holds

* layer ``towers`` (Polygon): one footprint per tower, attributes
  :data:`towerpipe.towers.records.TOWER_FIELDS`;
* layer ``tower_points`` (Point): the footprint centroid with the same attributes;
* in the zone's file, layers ``lines`` (LineString, :data:`towerpipe.towers.lines.LINE_FIELDS`),
  ``spans`` (LineString, :data:`towerpipe.towers.lines.SPAN_FIELDS`) and ``vanished_towers``
  (Polygon, :data:`towerpipe.towers.registry.REGISTRY_FIELDS`: registered towers the last run
  did not find again);
* in a block's file, layer ``conductor_points`` (Point: the conductor points found in the
  block, :data:`towerpipe.towers.wires.CONDUCTOR_FIELDS`), from which the zone's lines are built;
* table ``layer_styles``: the default QGIS style of each layer (as QGIS itself stores
  styles in a GeoPackage; :mod:`towerpipe.products.styles`), built from ``towerpipe/data/towers.qml``;
* ``gpkg_data_columns``: title and description (with units) of every field, and an
  enum constraint for ``review_status`` (GDAL reads it as a field domain);
* run metadata (``towerpipe_version``, ``model_name``, ``model_version``, ``model_choice``,
  ``config_hash``, ``run_time`` …) as GDAL dataset metadata, i.e. in the standard
  ``gpkg_metadata`` / ``gpkg_metadata_reference`` tables; read it with
  :func:`towerpipe.products.gpkg_read.read_metadata` or ``pyogrio.read_info(path)["dataset_metadata"]``.

Files are GeoPackage 1.2 (``PRAGMA user_version`` 10200, GDAL's layer creation option
``VERSION``), which GDAL 3.6 (QGIS LTR of Debian 12) opens without a warning and whose
R-tree triggers its validator accepts; GDAL >= 3.7 writes 1.4 by default. Values are
rounded as their :class:`towerpipe.io.fields.Field` says, geometries snapped to 1 cm.
Files are written to a temporary file in the destination folder and renamed into
place, so a reader never sees a half-written GeoPackage. A block without towers gets
valid empty layers with the full schema. Reading and merging the files:
:mod:`towerpipe.products.gpkg_read`.
"""

from __future__ import annotations

import json
import os
import sqlite3
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import geopandas as gpd
import pandas as pd
import pyogrio

from towerpipe.io.fields import Field, conform
from towerpipe.model.cards import config_hash
from towerpipe.products import styles

LAYER_TOWERS = "towers"
LAYER_POINTS = "tower_points"
LAYER_LINES = "lines"
LAYER_SPANS = "spans"
LAYER_VANISHED = "vanished_towers"
LAYER_CONDUCTORS = "conductor_points"
GEOMETRY_NAME = "geom"
#: GeoPackage version written (GDAL layer creation option ``VERSION``): 1.2, as GDAL 3.6.
GPKG_VERSION = "1.2"

__all__ = [
    "LAYER_TOWERS",
    "LAYER_POINTS",
    "LAYER_LINES",
    "LAYER_SPANS",
    "LAYER_VANISHED",
    "LAYER_CONDUCTORS",
    "GPKG_VERSION",
    "Layer",
    "write_gpkg",
    "write_towers_gpkg",
    "run_metadata",
    "default_style",
]


# --------------------------------------------------------------------------- styles
#: The default QGIS style of each styled layer (:mod:`towerpipe.products.styles`).
_STYLES: dict[str, styles.LayerStyle] = {
    LAYER_TOWERS: styles.TOWERS,
    LAYER_POINTS: styles.TOWER_POINTS,
    LAYER_LINES: styles.LINES,
    LAYER_SPANS: styles.SPANS,
    LAYER_VANISHED: styles.VANISHED,
    LAYER_CONDUCTORS: styles.CONDUCTORS,
}


def default_style(layer: str = LAYER_TOWERS, fields: Mapping[str, Field] | None = None) -> str:
    """The default QGIS style (QML text) of a layer of a tower GeoPackage.

    Parameters
    ----------
    layer
        A layer name (``"towers"``, ``"tower_points"``, ``"lines"`` …); ``"polygon"`` and
        ``"point"`` name the two tower layers.
    fields
        The layer's fields: their titles become the field aliases (default: the tower
        fields).
    """
    layer = {"polygon": LAYER_TOWERS, "point": LAYER_POINTS}.get(layer, layer)
    if layer not in _STYLES:
        raise ValueError(f"no style for layer {layer!r} (known: {', '.join(_STYLES)})")
    if fields is None:
        from towerpipe.towers.records import TOWER_FIELDS as fields
    return styles.qml(_STYLES[layer], fields)


def _styles_frame(layers: Sequence[Layer]) -> pd.DataFrame:
    """The ``layer_styles`` rows (QGIS schema) of the styled layers."""
    now = datetime.now(UTC).replace(microsecond=0).isoformat()
    rows = []
    for lay in layers:
        if lay.name not in _STYLES or lay.geometry_type is None:
            continue
        rows.append(
            {
                "f_table_catalog": "",
                "f_table_schema": "",
                "f_table_name": lay.name,
                "f_geometry_column": GEOMETRY_NAME,
                "styleName": f"towerpipe {lay.name}",
                "styleQML": default_style(lay.name, lay.fields),
                "styleSLD": "",
                "useAsDefault": True,
                "description": "towerpipe default style",
                "owner": "",
                "ui": "",
                "update_time": now,
            }
        )
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- metadata
def run_metadata(
    *,
    model_meta: Mapping[str, Any] | None = None,
    config: Mapping[str, Any] | None = None,
    run_time: str | None = None,
    **extra: Any,
) -> dict[str, str]:
    """Run metadata for :func:`write_towers_gpkg`.

    Parameters
    ----------
    model_meta
        ``{"name", "version", "sha256", "choice", ...}`` of the model used; a ``choice``
        (``{"mode", "reason"}``: why this model) is recorded as ``model_choice``.
    config
        The run configuration (hashed into ``config_hash``).
    run_time
        ISO timestamp (default: now, UTC).
    **extra
        More key/value pairs (e.g. ``zone``, ``block``), stored as strings.
    """
    from towerpipe import __version__

    model_meta = dict(model_meta or {})
    md = {
        "towerpipe_version": __version__,
        "model_name": str(model_meta.get("name", "")),
        "model_version": str(model_meta.get("version", "")),
        "model_sha256": str(model_meta.get("sha256", "")),
        # how the model was chosen (inference.model: auto picks per zone; towerpipe.model.choice)
        "model_choice": str((model_meta.get("choice") or {}).get("reason", "")),
        "config_hash": config_hash(config or {}),
        "run_time": run_time or datetime.now(UTC).replace(microsecond=0).isoformat(),
    }
    if model_meta.get("choice"):
        md["model_choice"] = json.dumps(model_meta["choice"], default=str)
    md.update({str(k): (v if isinstance(v, str) else json.dumps(v, default=str)) for k, v in extra.items()})
    return md


# --------------------------------------------------------------------------- writing
@dataclass
class Layer:
    """One layer to write: its table, schema and GeoPackage identification.

    ``geometry_type`` ``None`` writes an attribute table (no geometry).
    """

    name: str
    frame: pd.DataFrame
    fields: Mapping[str, Field]
    geometry_type: str | None
    identifier: str
    description: str


def _data_columns(con: sqlite3.Connection, layers: Sequence[Layer]) -> None:
    """``gpkg_data_columns`` (title, description) of every field; enums as constraints."""
    con.executescript("""
        CREATE TABLE gpkg_data_columns (
          table_name TEXT NOT NULL, column_name TEXT NOT NULL, name TEXT, title TEXT, description TEXT,
          mime_type TEXT, constraint_name TEXT,
          CONSTRAINT pk_gdc PRIMARY KEY (table_name, column_name),
          CONSTRAINT gdc_tn UNIQUE (table_name, name));
        CREATE TABLE gpkg_data_column_constraints (
          constraint_name TEXT NOT NULL, constraint_type TEXT NOT NULL, value TEXT, min NUMERIC,
          min_is_inclusive BOOLEAN, max NUMERIC, max_is_inclusive BOOLEAN, description TEXT,
          CONSTRAINT gdcc_ntv UNIQUE (constraint_name, constraint_type, value));
        INSERT INTO gpkg_extensions (table_name, column_name, extension_name, definition, scope) VALUES
          ('gpkg_data_columns', NULL, 'gpkg_schema', 'http://www.geopackage.org/spec/#extension_schema', 'read-write'),
          ('gpkg_data_column_constraints', NULL, 'gpkg_schema', 'http://www.geopackage.org/spec/#extension_schema',
           'read-write');
    """)
    enums: dict[str, tuple[str, ...]] = {}
    for lay in layers:
        for name, f in lay.fields.items():
            cname = None
            if f.enum:
                cname = f"{name}_values"
                if enums.setdefault(cname, f.enum) != f.enum:
                    cname = f"{lay.name}_{name}_values"
                    enums[cname] = f.enum
            con.execute(
                "INSERT INTO gpkg_data_columns (table_name, column_name, name, title, description, "
                "constraint_name) VALUES (?, ?, ?, ?, ?, ?)",
                (lay.name, name, name, f.title, f.description, cname),
            )
    for cname, values in enums.items():
        con.executemany(
            "INSERT INTO gpkg_data_column_constraints (constraint_name, constraint_type, value, "
            "description) VALUES (?, 'enum', ?, ?)",
            [(cname, v, v) for v in values],
        )


def _clean(path: Path) -> None:
    for leftover in (path, Path(str(path) + "-journal"), Path(str(path) + "-wal"), Path(str(path) + "-shm")):
        if leftover.exists():
            leftover.unlink()


def write_gpkg(
    path: str | os.PathLike[str],
    layers: Sequence[Layer],
    *,
    crs_wkt: Any = None,
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """Write layers, their styles, field descriptions and metadata to a GeoPackage, atomically.

    Parameters
    ----------
    path
        Destination ``.gpkg`` (replaced if it exists).
    layers
        The layers; each table is conformed to its fields (order, types, rounding).
    crs_wkt
        CRS of every spatial layer (WKT or anything pyproj reads); default: the first
        layer's. Required when no layer has one.
    metadata
        GeoPackage metadata (``gpkg_metadata``, GDAL dataset metadata).
    """
    path = Path(path)
    spatial = [lay for lay in layers if lay.geometry_type is not None]
    crs = (
        crs_wkt
        if crs_wkt is not None
        else next((lay.frame.crs for lay in spatial if getattr(lay.frame, "crs", None) is not None), None)
    )
    if spatial and crs is None:
        raise ValueError(f"{path}: no CRS for the tower GeoPackage; pass crs_wkt")
    md = {str(k): str(v) for k, v in (metadata or {}).items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.part.gpkg")  # fixed name: a rerun after a kill replaces it
    try:
        _clean(tmp)
        for i, lay in enumerate(layers):
            frame = conform(lay.frame, lay.fields, crs if lay.geometry_type else None)
            opts = {"IDENTIFIER": lay.identifier, "DESCRIPTION": lay.description}
            if lay.geometry_type is not None:
                opts.update(GEOMETRY_NAME=GEOMETRY_NAME, SPATIAL_INDEX="YES")
            pyogrio.write_dataframe(
                frame,
                tmp,
                layer=lay.name,
                driver="GPKG",
                geometry_type=lay.geometry_type,
                dataset_options={"VERSION": GPKG_VERSION} if i == 0 else None,
                dataset_metadata=(md or None) if i == 0 else None,
                layer_options=opts,
                append=False,
            )
        styles = _styles_frame(layers)
        if len(styles):
            pyogrio.write_dataframe(styles, tmp, layer="layer_styles", driver="GPKG", layer_options={"FID": "id"})
        with sqlite3.connect(tmp) as con:
            _data_columns(con, layers)
        con.close()
        os.replace(tmp, path)
        stale_pam = Path(str(path) + ".aux.xml")  # GDAL side-car of an older file: would shadow metadata
        if stale_pam.exists():
            stale_pam.unlink()
    finally:
        _clean(tmp)
    return path


def _tower_layers(towers: gpd.GeoDataFrame | None, crs: Any) -> list[Layer]:
    from towerpipe.io.fields import empty_frame
    from towerpipe.towers.records import TOWER_FIELDS

    gdf = towers if towers is not None and len(towers) else empty_frame(TOWER_FIELDS, crs)
    gdf = conform(gdf, TOWER_FIELDS, crs)
    pts = gpd.GeoDataFrame(
        gdf.drop(columns="geometry"),
        geometry=gpd.points_from_xy(gdf["centroid_x"].to_numpy(float), gdf["centroid_y"].to_numpy(float), crs=crs),
        crs=crs,
    )
    return [
        Layer(
            LAYER_TOWERS,
            gdf,
            TOWER_FIELDS,
            "Polygon",
            "Towers (footprints)",
            "Power transmission towers found by towerpipe: xy footprint of the tower points",
        ),
        Layer(
            LAYER_POINTS,
            pts,
            TOWER_FIELDS,
            "Point",
            "Towers (centroids)",
            "Power transmission towers found by towerpipe: footprint centroid",
        ),
    ]


def write_towers_gpkg(
    path: str | os.PathLike[str],
    towers: gpd.GeoDataFrame | None,
    *,
    crs_wkt: str | None = None,
    metadata: Mapping[str, Any] | None = None,
    lines: gpd.GeoDataFrame | None = None,
    spans: gpd.GeoDataFrame | None = None,
    vanished: gpd.GeoDataFrame | None = None,
    conductors: gpd.GeoDataFrame | None = None,
) -> Path:
    """Write the tower GeoPackage atomically.

    Parameters
    ----------
    path
        Destination ``.gpkg`` (replaced if it exists).
    towers
        Tower records (``towers`` of :func:`towerpipe.towers.extract.extract_towers`)
        (None or empty: empty layers with the full schema).
    crs_wkt
        CRS of the input point clouds (WKT or any pyproj-readable string);
        default: the CRS of ``towers``. Required when ``towers`` has no CRS.
    metadata
        Run metadata (see :func:`run_metadata`), stored as GeoPackage metadata.
    lines, spans, vanished
        The zone's lines, spans (:func:`towerpipe.towers.lines.build_lines`) and vanished towers
        (:func:`towerpipe.towers.registry.vanished`); each given table (even empty) is written
        as its layer.
    conductors
        Conductor points of a block (:func:`towerpipe.towers.wires.conductor_points`).

    Returns
    -------
    pathlib.Path
        The written file.
    """
    from towerpipe.io.fields import empty_frame
    from towerpipe.towers.lines import LINE_FIELDS, SPAN_FIELDS
    from towerpipe.towers.registry import REGISTRY_FIELDS
    from towerpipe.towers.wires import CONDUCTOR_FIELDS

    crs = crs_wkt if crs_wkt is not None else (towers.crs if towers is not None else None)
    if crs is None:
        raise ValueError(f"{path}: no CRS for the tower GeoPackage; pass crs_wkt")
    layers = _tower_layers(towers, crs)
    extra = [
        (
            lines,
            LAYER_LINES,
            LINE_FIELDS,
            "LineString",
            "Power lines",
            "Towers linked into lines by the conductors between them; vertices at the towers, in line order",
        ),
        (
            spans,
            LAYER_SPANS,
            SPAN_FIELDS,
            "LineString",
            "Spans",
            "Tower-to-tower spans: length, bearing, conductor points and clearance below them",
        ),
        (
            vanished,
            LAYER_VANISHED,
            REGISTRY_FIELDS,
            "Polygon",
            "Vanished towers",
            "Towers of the registry the last run did not find again (last footprint seen)",
        ),
        (
            conductors,
            LAYER_CONDUCTORS,
            CONDUCTOR_FIELDS,
            "Point",
            "Conductor points",
            "Points on overhead wires found in the block (they link the towers into lines)",
        ),
    ]
    for table, name, fields, gtype, ident, desc in extra:
        if table is not None:
            layers.append(Layer(name, table if len(table) else empty_frame(fields, crs), fields, gtype, ident, desc))
    md = {str(k): str(v) for k, v in (metadata or {}).items()}
    md.setdefault("n_towers", str(0 if towers is None else len(towers)))
    return write_gpkg(path, layers, crs_wkt=crs, metadata=md)
