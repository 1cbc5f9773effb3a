"""Reading tower GeoPackages (:mod:`towerpipe.products.gpkg`), and merging a zone's blocks into one.

Readers of the layers, the run metadata and the GeoPackage version of a file written by
:func:`towerpipe.products.gpkg.write_towers_gpkg`; :func:`concat_towers` joins one layer of
several files (each tower once), :func:`merge_gpkgs` writes the zone's ``towers.gpkg`` from
the blocks' files. GDAL's ``.aux.xml`` side-cars are never left behind by a read.
"""

from __future__ import annotations

import logging
import os
import sqlite3
from collections.abc import Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import pyogrio
import shapely

from towerpipe.errors import InputError
from towerpipe.products.gpkg import LAYER_POINTS, LAYER_TOWERS, write_towers_gpkg

log = logging.getLogger(__name__)

__all__ = [
    "read_towers",
    "read_metadata",
    "list_layers",
    "merge_gpkgs",
    "concat_towers",
    "gpkg_version",
]


# --------------------------------------------------------------------------- reading
@contextmanager
def _no_pam():
    """GDAL would otherwise leave a ``.aux.xml`` side-car copy of the metadata next to a file it reads."""
    previous = pyogrio.get_gdal_config_option("GDAL_PAM_ENABLED")
    pyogrio.set_gdal_config_options({"GDAL_PAM_ENABLED": "NO"})
    try:
        yield
    finally:
        pyogrio.set_gdal_config_options({"GDAL_PAM_ENABLED": previous})


def list_layers(path: str | os.PathLike[str]) -> list[str]:
    """Layer names of a GeoPackage."""
    try:
        with _no_pam():
            return [str(name) for name, _ in pyogrio.list_layers(path)]
    except Exception as exc:  # pyogrio raises several DataSource errors
        raise InputError(path, f"not a readable GeoPackage ({exc})") from exc


def read_towers(path: str | os.PathLike[str], layer: str = LAYER_TOWERS) -> gpd.GeoDataFrame:
    """Read a layer of a tower GeoPackage (raises :class:`InputError` when unreadable)."""
    try:
        with _no_pam():
            gdf = pyogrio.read_dataframe(path, layer=layer)
    except Exception as exc:  # pyogrio raises several DataSource/DataLayer errors
        raise InputError(path, f"not a readable tower GeoPackage ({exc}); rerun the towers step") from exc
    for col in ("line_id", "line_seq"):  # NULL-able integers come back as float
        if col in gdf.columns and gdf[col].dtype.kind == "f":
            gdf[col] = gdf[col].astype("Int64")
    return gdf


def read_metadata(path: str | os.PathLike[str]) -> dict[str, str]:
    """The run metadata stored by :func:`write_towers_gpkg`."""
    try:
        with _no_pam():
            return dict(pyogrio.read_info(path, layer=LAYER_TOWERS).get("dataset_metadata") or {})
    except Exception as exc:
        raise InputError(path, f"not a readable tower GeoPackage ({exc})") from exc


def concat_towers(
    paths: Sequence[str | os.PathLike[str]], layer: str = LAYER_TOWERS, *, crs_wkt: Any = None
) -> gpd.GeoDataFrame:
    """One layer of several tower GeoPackages, concatenated (one CRS, else :class:`InputError`).

    A tower reported by two blocks or zones (only possible when they overlap: the
    footprints intersect) is kept once, from the first file, with a warning.
    """
    frames, crs = [], None
    for p in paths:
        gdf = read_towers(p, layer)
        if gdf.crs is not None:
            if crs is None:
                crs = gdf.crs
            elif not gdf.crs.equals(crs):
                raise InputError(p, f"CRS {gdf.crs.name!r} differs from the other tower files ({crs.name!r})")
        if len(gdf):
            frames.append(gdf)
    crs = crs if crs is not None else crs_wkt
    if not frames:
        return gpd.GeoDataFrame(geometry=gpd.GeoSeries([], crs=crs), crs=crs)
    merged = gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), crs=crs)
    if layer in (LAYER_TOWERS, LAYER_POINTS):
        # one tower reported twice (blocks or zones that overlap: the footprints intersect) is
        # kept once, from the first file; two towers with one id that do not overlap are both
        # kept, for towerpipe.towers.registry.unique_ids to tell apart
        foot = merged.geometry.values if layer == LAYER_TOWERS else merged.geometry.buffer(0.5).values
        tree = shapely.STRtree(foot)
        a, b = tree.query(foot, predicate="intersects")
        later = np.zeros(len(merged), bool)
        for i, j in sorted(zip(a.tolist(), b.tolist())):
            if i < j and not later[i]:
                later[j] = True
        if later.any():
            log.warning(
                "%d tower(s) reported by more than one block or zone, kept once: %s",
                int(later.sum()),
                ", ".join(merged.loc[later, "tower_id"].astype(str).tolist()[:10]),
            )
            merged = merged.loc[~later]
        merged = merged.sort_values("tower_id", kind="stable")
    return merged.reset_index(drop=True)


def merge_gpkgs(
    paths: Sequence[str | os.PathLike[str]],
    out_path: str | os.PathLike[str],
    *,
    metadata: Mapping[str, Any] | None = None,
    crs_wkt: str | None = None,
    **layers: Any,
) -> Path:
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
    **layers
        ``lines``, ``spans``, ``vanished``: zone layers for :func:`write_towers_gpkg`.

    Returns
    -------
    pathlib.Path
        The written file (towers sorted by id, each id once).
    """
    from towerpipe.towers.registry import unique_ids

    merged = unique_ids(concat_towers(paths, crs_wkt=crs_wkt))
    crs = merged.crs if merged.crs is not None else crs_wkt
    if crs is None:
        raise ValueError(f"{out_path}: no inputs and no crs_wkt given")
    md = dict(metadata) if metadata is not None else (read_metadata(paths[0]) if paths else {})
    md["blocks"] = str(len(paths))
    md["n_towers"] = str(len(merged))
    if metadata is None:
        md.pop("block", None)
    wkt = crs.to_wkt() if hasattr(crs, "to_wkt") else crs
    return write_towers_gpkg(out_path, merged if len(merged) else None, crs_wkt=wkt, metadata=md, **layers)


def gpkg_version(path: str | os.PathLike[str]) -> int:
    """``PRAGMA user_version`` of a GeoPackage (10200 for 1.2)."""
    with sqlite3.connect(f"file:{Path(path).resolve()}?mode=ro", uri=True) as con:
        version = int(con.execute("PRAGMA user_version").fetchone()[0])
    con.close()
    return version
