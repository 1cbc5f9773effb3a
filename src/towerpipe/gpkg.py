"""The tower GeoPackage: per-block ``towers.gpkg`` and the zone-level merge.

A tower GeoPackage holds

* layer ``towers`` (Polygon): one footprint per tower, attributes
  :data:`towerpipe.towers.TOWER_COLUMNS`;
* layer ``tower_points`` (Point): the footprint centroid with the same attributes;
* table ``layer_styles``: the default QGIS style of both layers (as QGIS itself
  stores styles in a GeoPackage), from ``towerpipe/data/towers.qml``;
* run metadata (``towerpipe_version``, ``model_name``, ``model_version``, ``model_choice``,
  ``config_hash``, ``run_time`` …) as GDAL dataset metadata, i.e. in the standard
  ``gpkg_metadata`` / ``gpkg_metadata_reference`` tables; read it with
  :func:`read_metadata` or ``pyogrio.read_info(path)["dataset_metadata"]``.

Files are written to a temporary file in the destination folder and renamed
into place, so a reader never sees a half-written GeoPackage. A block without
towers gets valid empty layers with the full schema.
"""

from __future__ import annotations

import json
import logging
import os
import re
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path
from typing import Any

import geopandas as gpd
import pandas as pd
import pyogrio

from towerpipe.errors import InputError
from towerpipe.modelcard import config_hash
from towerpipe.towers import TOWER_COLUMNS, empty_towers

log = logging.getLogger(__name__)

LAYER_TOWERS = "towers"
LAYER_POINTS = "tower_points"
GEOMETRY_NAME = "geom"


def default_style(geometry: str = "polygon") -> str:
    """The default QGIS style (QML text) of the ``towers`` (``"polygon"``) or
    ``tower_points`` (``"point"``) layer."""
    qml = resources.files("towerpipe").joinpath("data/towers.qml").read_text(encoding="utf-8")
    if geometry == "polygon":
        return qml
    if geometry != "point":
        raise ValueError(f"geometry must be 'polygon' or 'point', not {geometry!r}")
    marker = (
        '<symbols>\n      <symbol type="marker" name="0" alpha="1" clip_to_extent="1" force_rhr="0">\n'
        '        <layer class="SimpleMarker" enabled="1" locked="0" pass="0">\n'
        '          <Option type="Map">\n'
        '            <Option name="name" type="QString" value="triangle"/>\n'
        '            <Option name="color" type="QString" value="227,26,28,255"/>\n'
        '            <Option name="outline_color" type="QString" value="103,0,13,255"/>\n'
        '            <Option name="outline_width" type="QString" value="0.3"/>\n'
        '            <Option name="outline_width_unit" type="QString" value="MM"/>\n'
        '            <Option name="size" type="QString" value="3.2"/>\n'
        '            <Option name="size_unit" type="QString" value="MM"/>\n'
        '          </Option>\n        </layer>\n      </symbol>\n    </symbols>'
    )
    qml = re.sub(r"<symbols>.*?</symbols>", marker, qml, count=1, flags=re.S)
    qml = qml.replace('placement="1"', 'placement="0"')  # around point instead of around centroid
    return qml.replace("<layerGeometryType>2</layerGeometryType>", "<layerGeometryType>0</layerGeometryType>")


def run_metadata(*, model_meta: Mapping[str, Any] | None = None, config: Mapping[str, Any] | None = None,
                 run_time: str | None = None, **extra: Any) -> dict[str, str]:
    """Run metadata for :func:`write_towers_gpkg`.

    Parameters
    ----------
    model_meta
        ``{"name", "version", "sha256", ...}`` of the model used.
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
        # how the model was chosen (inference.model: auto picks per zone; towerpipe.modelchoice)
        "model_choice": str((model_meta.get("choice") or {}).get("reason", "")),
        "config_hash": config_hash(config or {}),
        "run_time": run_time or datetime.now(timezone.utc).replace(microsecond=0).isoformat(),
    }
    md.update({str(k): (v if isinstance(v, str) else json.dumps(v, default=str)) for k, v in extra.items()})
    return md


def _normalise(towers: gpd.GeoDataFrame | None, crs: Any) -> gpd.GeoDataFrame:
    """Columns in :data:`TOWER_COLUMNS` order with the contract dtypes."""
    if towers is None or len(towers) == 0:
        return empty_towers(crs)
    missing = [c for c in TOWER_COLUMNS if c not in towers.columns]
    if missing:
        raise ValueError(f"tower table lacks columns {missing}")
    out = towers[list(TOWER_COLUMNS)].copy()
    for c, t in TOWER_COLUMNS.items():
        out[c] = out[c].astype(object if t == "str" else t)
    return gpd.GeoDataFrame(out, geometry=gpd.GeoSeries(towers.geometry.values, crs=crs), crs=crs).reset_index(drop=True)


def _styles_frame() -> pd.DataFrame:
    """The ``layer_styles`` rows (QGIS schema) of both layers."""
    now = datetime.now(timezone.utc).replace(microsecond=0).isoformat()
    rows = []
    for layer, geom in ((LAYER_TOWERS, "polygon"), (LAYER_POINTS, "point")):
        rows.append({
            "f_table_catalog": "", "f_table_schema": "", "f_table_name": layer,
            "f_geometry_column": GEOMETRY_NAME, "styleName": f"towerpipe {layer}",
            "styleQML": default_style(geom), "styleSLD": "", "useAsDefault": True,
            "description": "towerpipe default style", "owner": "", "ui": "", "update_time": now,
        })
    return pd.DataFrame(rows)


def write_towers_gpkg(path: str | os.PathLike[str], towers: gpd.GeoDataFrame | None, *,
                      crs_wkt: str | None = None, metadata: Mapping[str, Any] | None = None) -> Path:
    """Write the tower GeoPackage atomically.

    Parameters
    ----------
    path
        Destination ``.gpkg`` (replaced if it exists).
    towers
        Tower records as returned by :func:`towerpipe.towers.extract_towers`
        (None or empty: empty layers with the full schema).
    crs_wkt
        CRS of the input point clouds (WKT or any pyproj-readable string);
        default: the CRS of ``towers``. Required when ``towers`` has no CRS.
    metadata
        Run metadata (see :func:`run_metadata`), stored as GeoPackage metadata.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    path = Path(path)
    crs = crs_wkt if crs_wkt is not None else (towers.crs if towers is not None else None)
    if crs is None:
        raise ValueError(f"{path}: no CRS for the tower GeoPackage; pass crs_wkt")
    gdf = _normalise(towers, crs)
    pts = gdf.copy()
    pts = gpd.GeoDataFrame(pts.drop(columns="geometry"),
                           geometry=gpd.points_from_xy(gdf["centroid_x"].to_numpy(float),
                                                       gdf["centroid_y"].to_numpy(float), crs=crs), crs=crs)
    md = {str(k): str(v) for k, v in (metadata or {}).items()}
    md.setdefault("n_towers", str(len(gdf)))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.part.gpkg")  # fixed name: a rerun after a kill replaces it
    try:
        if tmp.exists():
            tmp.unlink()
        opts = {"GEOMETRY_NAME": GEOMETRY_NAME, "SPATIAL_INDEX": "YES"}
        pyogrio.write_dataframe(gdf, tmp, layer=LAYER_TOWERS, driver="GPKG", geometry_type="Polygon",
                                dataset_metadata=md or None,
                                layer_options=dict(opts, IDENTIFIER="Towers (footprints)",
                                                   DESCRIPTION="Power transmission towers found by towerpipe: "
                                                               "xy footprint of the tower points"))
        pyogrio.write_dataframe(pts, tmp, layer=LAYER_POINTS, driver="GPKG", geometry_type="Point",
                                layer_options=dict(opts, IDENTIFIER="Towers (centroids)",
                                                   DESCRIPTION="Power transmission towers found by towerpipe: "
                                                               "footprint centroid"))
        pyogrio.write_dataframe(_styles_frame(), tmp, layer="layer_styles", driver="GPKG",
                                layer_options={"FID": "id"})
        os.replace(tmp, path)
        stale_pam = Path(str(path) + ".aux.xml")  # GDAL side-car of an older file: would shadow metadata
        if stale_pam.exists():
            stale_pam.unlink()
    finally:
        for leftover in (tmp, Path(str(tmp) + "-journal"), Path(str(tmp) + "-wal"), Path(str(tmp) + "-shm")):
            if leftover.exists():
                leftover.unlink()
    return path


def read_towers(path: str | os.PathLike[str], layer: str = LAYER_TOWERS) -> gpd.GeoDataFrame:
    """Read a layer of a tower GeoPackage (raises :class:`InputError` when unreadable)."""
    # GDAL would otherwise leave a ``.aux.xml`` side-car copy of the metadata next to the file
    previous = pyogrio.get_gdal_config_option("GDAL_PAM_ENABLED")
    pyogrio.set_gdal_config_options({"GDAL_PAM_ENABLED": "NO"})
    try:
        return pyogrio.read_dataframe(path, layer=layer)
    except Exception as exc:  # pyogrio raises several DataSource/DataLayer errors
        raise InputError(path, f"not a readable tower GeoPackage ({exc}); rerun the towers step") from exc
    finally:
        pyogrio.set_gdal_config_options({"GDAL_PAM_ENABLED": previous})


def read_metadata(path: str | os.PathLike[str]) -> dict[str, str]:
    """The run metadata stored by :func:`write_towers_gpkg`."""
    try:
        return dict(pyogrio.read_info(path, layer=LAYER_TOWERS).get("dataset_metadata") or {})
    except Exception as exc:
        raise InputError(path, f"not a readable tower GeoPackage ({exc})") from exc


def merge_gpkgs(paths: Sequence[str | os.PathLike[str]], out_path: str | os.PathLike[str], *,
                metadata: Mapping[str, Any] | None = None, crs_wkt: str | None = None) -> Path:
    """Assemble per-block tower GeoPackages into one (zone-level) GeoPackage.

    Parameters
    ----------
    paths
        Per-block files written by :func:`write_towers_gpkg` (empty ones allowed).
    out_path
        Destination ``.gpkg`` (written atomically).
    metadata
        Run metadata for the merged file; default: that of the first input, with
        ``blocks`` (number of inputs) and ``n_towers`` updated.
    crs_wkt
        CRS when there are no inputs; otherwise all inputs must share one CRS.

    Returns
    -------
    pathlib.Path
        The written file. Tower ids are unique: a tower reported by two blocks
        (only possible when blocks overlap) is kept once, with a warning.
    """
    frames, crs, first_md = [], None, None
    for p in paths:
        gdf = read_towers(p)
        if first_md is None:
            first_md = read_metadata(p)
        if gdf.crs is not None:
            if crs is None:
                crs = gdf.crs
            elif not gdf.crs.equals(crs):
                raise InputError(p, f"CRS {gdf.crs.name!r} differs from the other tower files ({crs.name!r})")
        frames.append(gdf)
    crs = crs if crs is not None else crs_wkt
    if crs is None:
        raise ValueError(f"{out_path}: no inputs and no crs_wkt given")
    nonempty = [f for f in frames if len(f)]
    if nonempty:
        merged = gpd.GeoDataFrame(pd.concat(nonempty, ignore_index=True), crs=crs)
        dup = merged["tower_id"].duplicated(keep="first")
        if dup.any():
            log.warning("%s: %d tower id(s) reported by more than one block, kept once: %s", out_path,
                        int(dup.sum()), ", ".join(merged.loc[dup, "tower_id"].astype(str).tolist()[:10]))
            merged = merged.loc[~dup]
        merged = merged.sort_values("tower_id", kind="stable").reset_index(drop=True)
    else:
        merged = None
    md = dict(metadata) if metadata is not None else dict(first_md or {})
    md["blocks"] = str(len(frames))
    md["n_towers"] = str(0 if merged is None else len(merged))
    if metadata is None:
        md.pop("block", None)
    wkt = crs.to_wkt() if hasattr(crs, "to_wkt") else crs
    return write_towers_gpkg(out_path, merged, crs_wkt=wkt, metadata=md)
