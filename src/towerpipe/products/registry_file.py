"""The tower registry file: the zone's ``registry.gpkg`` read (or seeded from a published
``towers.gpkg``) and written, and the review statuses analysts edited in the published products.

What the registry holds and how ids are assigned from it is :mod:`towerpipe.towers.registry`'s.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import geopandas as gpd
import pandas as pd

from towerpipe.errors import InputError
from towerpipe.io.fields import conform
from towerpipe.products.gpkg import LAYER_TOWERS, LAYER_VANISHED, Layer, write_gpkg
from towerpipe.products.gpkg_read import list_layers, read_towers
from towerpipe.towers.registry import (
    ACTIVE,
    REGISTRY_FIELDS,
    REVIEW_DEFAULT,
    REVIEW_STATUSES,
    VANISHED,
    empty_registry,
)

log = logging.getLogger(__name__)

#: Layer of the registry in ``registry.gpkg``.
REGISTRY_LAYER = "towers"


def read_registry(*paths: str | os.PathLike[str] | None) -> gpd.GeoDataFrame:
    """The registry: the first of ``paths`` that exists.

    A path is either a registry (``registry.gpkg``, layer ``towers`` with
    :data:`towerpipe.towers.registry.REGISTRY_FIELDS`) or a published zone ``towers.gpkg`` (its ``towers`` and
    ``vanished_towers`` layers, used when the registry itself was deleted with the work
    directory). A file with towers of an older format (text ids) gives an empty registry.
    """
    for p in paths:
        if p is None or not Path(p).is_file():
            continue
        layers = list_layers(p)
        frames = []
        for layer in (REGISTRY_LAYER, LAYER_TOWERS, LAYER_VANISHED):
            if layer in layers and layer not in [f[0] for f in frames]:
                frames.append((layer, read_towers(p, layer)))
        if not frames:
            raise InputError(p, "holds no tower layer; delete it to start a new tower registry")
        parts = []
        for layer, gdf in frames:
            if not len(gdf) or not pd.api.types.is_integer_dtype(gdf["tower_id"]):
                continue
            gdf = gdf.copy()
            if "status" not in gdf.columns:
                gdf["status"] = VANISHED if layer == LAYER_VANISHED else ACTIVE
            for c in ("first_seen", "last_seen", "vanished_since"):
                if c not in gdf.columns:
                    gdf[c] = gdf.get("processed_at") if c != "vanished_since" else pd.NaT
            if "review_status" not in gdf.columns:
                gdf["review_status"] = REVIEW_DEFAULT
            parts.append(conform(gdf, REGISTRY_FIELDS))
        if not parts:
            log.info("%s: no towers with integer ids; starting a new registry", p)
            return empty_registry(frames[0][1].crs)
        reg = gpd.GeoDataFrame(pd.concat(parts, ignore_index=True), crs=parts[0].crs)
        return reg.drop_duplicates("tower_id", keep="first").reset_index(drop=True)
    return empty_registry()


def _file_reviews(path: str | os.PathLike[str] | None, layers: tuple[str, ...]) -> dict[int, str]:
    """Tower id -> review status of every tower of ``layers`` of a published ``towers.gpkg`` (a
    valid status only; a file of an older version, with text ids, holds none)."""
    if path is None or not Path(path).is_file():
        return {}
    out: dict[int, str] = {}
    present = list_layers(path)
    for layer in layers:
        if layer not in present:
            continue
        gdf = read_towers(path, layer)
        if not len(gdf) or "review_status" not in gdf.columns or not pd.api.types.is_integer_dtype(gdf["tower_id"]):
            continue
        for tid, status in zip(gdf["tower_id"].astype("int64"), gdf["review_status"], strict=True):
            if status in REVIEW_STATUSES:
                out[int(tid)] = str(status)
    return out


def published_reviews(path: str | os.PathLike[str] | None, registry: gpd.GeoDataFrame) -> dict[int, str]:
    """Review statuses analysts changed in a published ``towers.gpkg`` (vs the registry)."""
    if not len(registry):
        return {}
    known = dict(zip(registry["tower_id"].astype("int64"), registry["review_status"]))
    return {
        tid: status
        for tid, status in _file_reviews(path, (LAYER_TOWERS, LAYER_VANISHED)).items()
        if tid in known and known[tid] != status
    }


def reviewed_towers(path: str | os.PathLike[str] | None) -> dict[int, str]:
    """Tower id -> status of the towers an analyst has reviewed (``confirmed`` or ``rejected``) in
    a published ``towers.gpkg`` (its ``towers`` layer); empty without the file."""
    return {tid: status for tid, status in _file_reviews(path, (LAYER_TOWERS,)).items() if status != REVIEW_DEFAULT}


def write_registry(path: str | os.PathLike[str], registry: gpd.GeoDataFrame, crs_wkt: str | None = None) -> Path:
    """Write the registry atomically (GeoPackage, layer ``towers``)."""
    return write_gpkg(
        path,
        [
            Layer(
                REGISTRY_LAYER,
                registry,
                REGISTRY_FIELDS,
                "Polygon",
                "Tower registry",
                "Every tower the zone has found, with its stable id",
            )
        ],
        crs_wkt=crs_wkt,
        metadata={"content": "towerpipe tower registry"},
    )
