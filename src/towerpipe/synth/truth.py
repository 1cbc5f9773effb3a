"""What a generated zone records beside its blocks: the tower truth and the zone metadata."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import geopandas as gpd
import numpy as np

TRUTH_GPKG = "towers_truth.gpkg"
TRUTH_GEOJSON = "towers_truth.geojson"
META_JSON = "synth_meta.json"
#: Columns of the truth table, in order.
TRUTH_COLUMNS = [
    "tower_id",
    "design",
    "height",
    "base_z",
    "base_width",
    "x",
    "y",
    "centroid_x",
    "centroid_y",
    "n_points",
    "block",
    "blocks",
    "line_id",
    "geometry",
]


@dataclass
class ZoneTruth:
    """What a zone generator wrote.

    Attributes
    ----------
    out_dir
        The zone directory.
    blocks
        One dict per block: ``name``, ``path``, ``bounds``, ``n_points``, ``counts`` (per class).
    towers
        The truth table (GeoDataFrame, layer ``towers`` of the sidecar).
    spans
        (S, 2) consecutive tower ids joined by wires.
    meta
        Everything in ``synth_meta.json``.
    """

    out_dir: Path
    blocks: list[dict]
    towers: gpd.GeoDataFrame
    spans: np.ndarray
    meta: dict


def write_truth(out: Path, towers: gpd.GeoDataFrame) -> None:
    """Write the GeoPackage (layer ``towers``) and the GeoJSON twin."""
    for f in (TRUTH_GPKG, TRUTH_GEOJSON):
        (out / f).unlink(missing_ok=True)
    towers.to_file(out / TRUTH_GPKG, layer="towers", driver="GPKG", engine="pyogrio")
    towers.to_file(out / TRUTH_GEOJSON, driver="GeoJSON", engine="pyogrio")
