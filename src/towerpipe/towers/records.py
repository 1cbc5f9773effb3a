"""The tower record: the fields of a tower (the GeoPackage's ``towers`` and ``tower_points``
layers, :func:`towerpipe.towers.extract.extract_towers`' rows) and an empty table of them."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from towerpipe.io.fields import DATETIME, Field, conform, dtypes, empty_frame, join_values
from towerpipe.towers.registry import REVIEW_STATUSES
from towerpipe.towers.shape import OBJECT_BUFFER_M, PEAK_CORE_RADIUS, SHAPE_VIEWS

__all__ = ["TOWER_COLUMNS", "TOWER_FIELDS", "empty_towers", "tower_record", "towers_frame"]

#: Fields of a tower record (besides the footprint geometry), in order: the GeoPackage
#: layers ``towers`` and ``tower_points`` use exactly these.
TOWER_FIELDS: dict[str, Field] = {
    "tower_id": Field(
        "int64",
        "Tower id",
        "Stable id (docs/products.md): the first-seen footprint centroid on a 1 m grid, "
        "(x mod 9e7) * 1e8 + (y mod 1e8); kept from run to run by the zone's registry. The "
        "TowerpipeTowerId of the tower's points in the classified blocks",
    ),
    "zone": Field("str", "Zone", "Zone name"),
    "block": Field("str", "Owning block", "Block holding the footprint centroid: the block that reports the tower"),
    "blocks": Field("str", "Blocks touched", "Blocks the tower's points come from, ';'-separated"),
    "centroid_x": Field("float64", "Centroid X (m)", "Footprint centroid, CRS units (m)", 2),
    "centroid_y": Field("float64", "Centroid Y (m)", "Footprint centroid, CRS units (m)", 2),
    "height_m": Field("float64", "Height (m)", "Height of the tower: top_z - base_z (m)", 2),
    "base_z": Field(
        "float64", "Base elevation (m)", "Ground elevation at the tower: median of z - HAG over its points (m)", 2
    ),
    "top_z": Field("float64", "Top elevation (m)", "Elevation of the tower's highest point (m)", 2),
    "footprint_area_m2": Field("float64", "Footprint area (m²)", "Area of the xy footprint (m²)", 2),
    "footprint_width_m": Field(
        "float64", "Footprint width (m)", "Short side of the footprint's minimum rotated rectangle (m)", 2
    ),
    "footprint_length_m": Field(
        "float64", "Footprint length (m)", "Long side of the footprint's minimum rotated rectangle (m)", 2
    ),
    "edge_distance_m": Field(
        "float64",
        "Distance to block edge (m)",
        "Distance from the centroid to the nearest edge of the owning block (m)",
        2,
    ),
    "n_points": Field("int64", "Points", "Points of the tower: those classified 15 in the classified blocks"),
    "prob_mean": Field(
        "float64", "Mean probability", "Mean single-view tower probability (0-1) of the points of its cluster", 3
    ),
    "prob_max": Field(
        "float64", "Max probability", "Highest single-view tower probability (0-1) of the points of its cluster", 3
    ),
    "shape_score": Field(
        "float64",
        "Shape score",
        "How much the object under the footprint, or its core around the top when that passed it "
        "(rule 9), looks like a tower and not a tree, roof or crane (0-1, towerpipe.towers.shape); "
        "a tower below towers.min_shape_score is reported only when rule 12 (towers.vouch_height, "
        "towers.vouch_low_height) or rule 13 (towers.tall_shape_score) keeps it, both on by default; "
        "NULL without the shape check",
        3,
    ),
    "shape_view": Field(
        "str",
        "Shape view",
        f"What shape_score judged: object (every point within {OBJECT_BUFFER_M:g} m of the footprint) or "
        f"core (those within {PEAK_CORE_RADIUS:g} m of the top, rule 9: the whole object looked like "
        "crowns and the segmenter gave no confident part to judge instead; a tower among trees, or a "
        "crown: worth a look); NULL without the shape check",
        enum=SHAPE_VIEWS,
    ),
    "wire_support": Field(
        "float64",
        "Conductor support (0-1)",
        "Share (0-1) of the 80-160 m ring around the base reached by a conductor pointing at "
        "it; NULL when unknown: no data around, or a line through the tower could leave the "
        "surveyed area unseen (towers.wire_line_coverage)",
        3,
    ),
    "line_id": Field(
        "Int64",
        "Line id",
        "Line of the tower (layer lines of the zone's file): the smallest tower_id on the line; "
        "NULL when the tower is linked to no other, and in a block's file (lines are built when "
        "the zone is assembled)",
    ),
    "line_seq": Field(
        "Int64",
        "Position on the line",
        "1, 2, … along the line (layer lines of the zone's file); NULL off a line and in a block's file",
    ),
    "line_chainage_m": Field(
        "float64", "Chainage (m)", "Distance along the line from its first tower, through the towers (m)", 2
    ),
    "bearing_deg": Field(
        "float64",
        "Line bearing (°)",
        "Azimuth of the line at the tower, degrees clockwise from grid north, toward increasing "
        "line_seq (at an angle tower the bisector of its two spans); the crossarm is "
        "perpendicular. For a tower on no line, the axis of its conductors (0-180); NULL "
        "when no conductor was found, and in a block's file (set with the lines, when the zone "
        "is assembled)",
        1,
    ),
    "deflection_deg": Field(
        "float64",
        "Line deflection (°)",
        "Angle the line turns at the tower (0 = straight through; angle towers); NULL at the ends of a line",
        1,
    ),
    "review_status": Field(
        "str",
        "Review status",
        "Analyst review: unreviewed (default), confirmed or rejected; kept from run to run by the registry",
        enum=REVIEW_STATUSES,
    ),
    "first_seen": Field(DATETIME, "First seen (UTC)", "When the tower was first found (when its id was made)"),
    "source_files": Field("str", "Source files", "Absolute paths of the input files of its blocks, ';'-separated"),
    "model_name": Field("str", "Model", "Model that predicted the tower points"),
    "model_version": Field("str", "Model version", "Version of that model"),
    "processed_at": Field(DATETIME, "Processed at (UTC)", "Time of the towers step"),
}
#: Column name → dtype of :data:`TOWER_FIELDS`.
TOWER_COLUMNS: dict[str, str] = dtypes(TOWER_FIELDS)


def empty_towers(crs: Any = None) -> gpd.GeoDataFrame:
    """An empty tower table with the full schema (:data:`TOWER_FIELDS` + Polygon geometry)."""
    return empty_frame(TOWER_FIELDS, crs)


def tower_record(
    footprint: shapely.Polygon,
    z: np.ndarray,
    hag: np.ndarray,
    prob: np.ndarray,
    *,
    tower_id: int,
    zone: str,
    block: str,
    block_bounds: Sequence[float],
    touched: Sequence[str],
    n_points: int,
    shape_score: float,
    shape_view: str | None,
    wire_support: float,
    review_status: str,
    first_seen: Any,
    processed_at: pd.Timestamp,
    source_files: Mapping[str, str],
    model_meta: Mapping[str, Any],
) -> dict[str, Any]:
    """The record of one accepted tower (:data:`TOWER_FIELDS`; the footprint is its geometry).

    Parameters
    ----------
    footprint
        The tower's xy footprint.
    z, hag, prob
        Elevation, height above ground and single-view probability of its cluster's points: its
        top, base, height and ``prob_mean`` / ``prob_max``.
    touched
        The blocks its points come from; ``source_files`` maps a block to its input file.
    first_seen
        From the registry (``None`` or NaT: first seen now, ``processed_at``).
    n_points, tower_id, zone, block, block_bounds, shape_score, shape_view, wire_support, review_status, model_meta
        As recorded (``block_bounds``: the owning block's, for ``edge_distance_m``).
    """
    xmin, ymin, xmax, ymax = (float(v) for v in block_bounds)
    c = footprint.centroid
    rect = shapely.oriented_envelope(footprint)
    ring = np.asarray(rect.exterior.coords) if isinstance(rect, shapely.Polygon) else np.zeros((2, 2))
    sides = np.hypot(*np.diff(ring[:3], axis=0).T) if len(ring) >= 3 else np.zeros(2)
    # top and base to the cm, and the height their difference: height_m = top_z - base_z exactly
    top = round(float(np.max(z)), 2)
    base = round(float(np.median(np.asarray(z) - hag)), 2)
    return {
        "tower_id": tower_id,
        "zone": str(zone),
        "block": str(block),
        "blocks": join_values(touched),
        "centroid_x": float(c.x),
        "centroid_y": float(c.y),
        "height_m": round(top - base, 2),
        "base_z": base,
        "top_z": top,
        "footprint_area_m2": float(footprint.area),
        "footprint_width_m": float(np.min(sides)),
        "footprint_length_m": float(np.max(sides)),
        "edge_distance_m": float(min(c.x - xmin, xmax - c.x, c.y - ymin, ymax - c.y)),
        "n_points": int(n_points),
        "prob_mean": float(np.mean(prob)),
        "prob_max": float(np.max(prob)),
        "shape_score": shape_score,
        "shape_view": shape_view,
        "wire_support": wire_support,
        "line_id": None,
        "line_seq": None,
        "line_chainage_m": np.nan,
        "bearing_deg": np.nan,
        "deflection_deg": np.nan,
        "review_status": review_status,
        "first_seen": first_seen if first_seen is not None and pd.notna(first_seen) else processed_at,
        "source_files": join_values(os.path.abspath(source_files[b]) for b in touched if b in source_files),
        "model_name": str(model_meta.get("name", "")),
        "model_version": str(model_meta.get("version", "")),
        "processed_at": processed_at,
    }


def towers_frame(rows: Sequence[dict[str, Any]], footprints: Sequence[shapely.Polygon], crs: Any) -> gpd.GeoDataFrame:
    """The tower table of ``rows`` (:func:`tower_record`) and their footprints, sorted by ``tower_id``
    and conformed to :data:`TOWER_FIELDS`; empty (full schema) without rows."""
    if not rows:
        return empty_towers(crs)
    gdf = gpd.GeoDataFrame(list(rows), geometry=list(footprints), crs=crs)
    return conform(gdf.sort_values("tower_id", kind="stable"), TOWER_FIELDS, crs)
