"""Stable tower ids: the registry of the towers a zone has found.

A tower keeps its id from run to run, whatever the model, the thresholds or the zone's
name, so an analyst's review status and edits follow it.

**Where ids are assigned.** Per-block products (``towers/<block>.gpkg``, the per-point
id of each classified block) are written by parallel per-block jobs, before the zone
is assembled, so an id cannot come from a zone-wide counter. It is assigned in the
towers job of a block, from two things that job can read:

1. the zone's **registry** (:func:`towerpipe.products.registry_file.read_registry`), as the last
   assembly left it: a tower whose footprint intersects a registered footprint, or whose centroid is within
   :data:`MATCH_DISTANCE` (5 m) of a registered one, takes that tower's id (one to one,
   nearest first, as :func:`towerpipe.towers.matching.match_towers` pairs towers);
2. otherwise a **new id derived from where the tower is first seen**
   (:func:`location_id`): its footprint centroid on a 1 m grid. Every job that sees the
   tower (the block that owns it and the neighbour it reaches into) derives the same id
   from the same points, with no coordination.

The assembly of the zone then updates the registry (:func:`update_registry`): new towers
are added, found ones refreshed, and registered towers not found again are kept with
``status = "vanished"`` (listed in the zone's ``vanished_towers`` layer and QA index);
one found again later takes its id back. A tower of a block that failed is left as it
was. The registry is read by the towers jobs but is not a Snakemake input of them (it
is written after them: an input would be a cycle), so updating it reruns nothing.

**Id format.** ``tower_id`` is an integer (int64 in the GeoPackage, uint64 in the
classified blocks' :data:`towerpipe.io.lasformat.TOWER_ID_DIMENSION`), the first-seen centroid
``(x, y)`` rounded to the metre: ``(x mod 9e7) * 1e8 + (y mod 1e8)``, e.g. ``40011304600326``
for (400 113, 4 600 326). It holds no zone name, reads as easting and northing, is unique
within any 90 000 km of a projected CRS, and stays below 2**53 (exact in a float64 too). 0
means "no tower". A new tower whose location id is already registered (a tower that
has drifted away from its first position) takes the next free northing metre.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd

from towerpipe.io.fields import DATETIME, Field, conform, empty_frame

log = logging.getLogger(__name__)

#: Centroid distance (m) under which a tower takes a registered tower's id (footprints
#: that intersect match at any distance).
MATCH_DISTANCE = 5.0
#: Review status of a tower: set by analysts, kept by the registry.
REVIEW_STATUSES = ("unreviewed", "confirmed", "rejected")
#: Review status of a tower nobody has looked at.
REVIEW_DEFAULT = REVIEW_STATUSES[0]
#: Registry status of a tower found by the last assembly / not found by it.
ACTIVE, VANISHED = "active", "vanished"

_X_MOD = 90_000_000
_Y_MOD = 100_000_000

#: Fields of the registry (layer ``towers`` of ``registry.gpkg``) and of the zone's
#: ``vanished_towers`` layer; geometry: the last footprint seen.
REGISTRY_FIELDS: dict[str, Field] = {
    "tower_id": Field("int64", "Tower id", "Stable tower id (see docs/products.md): first-seen centroid on a 1 m grid"),
    "status": Field(
        "str",
        "Status",
        "active: found by the last run; vanished: registered but not found since vanished_since",
        enum=(ACTIVE, VANISHED),
    ),
    "block": Field("str", "Block", "Block that held the tower when it was last seen"),
    "centroid_x": Field("float64", "Centroid X (m)", "Footprint centroid when last seen, CRS units (m)", 2),
    "centroid_y": Field("float64", "Centroid Y (m)", "Footprint centroid when last seen, CRS units (m)", 2),
    "height_m": Field("float64", "Height (m)", "Height when last seen: top_z - base_z (m)", 2),
    "first_seen": Field(DATETIME, "First seen (UTC)", "When the tower was first found (its id was made)"),
    "last_seen": Field(DATETIME, "Last seen (UTC)", "When a run last found the tower"),
    "vanished_since": Field(
        DATETIME, "Vanished since (UTC)", "First run that did not find the tower again; NULL while it is found"
    ),
    "review_status": Field(
        "str",
        "Review status",
        "Analyst review: unreviewed, confirmed or rejected (kept from run to run)",
        enum=REVIEW_STATUSES,
    ),
}


# --------------------------------------------------------------------------- ids
def location_id(x: float, y: float) -> int:
    """The id a tower first seen at ``(x, y)`` gets: ``(round(x) mod 9e7) * 1e8 + (round(y) mod 1e8)``."""
    return (int(np.round(x)) % _X_MOD) * _Y_MOD + (int(np.round(y)) % _Y_MOD)


def _free_id(x: float, y: float, taken: set[int]) -> int:
    """:func:`location_id`, moved north metre by metre while it is taken (or 0)."""
    for dy in range(_Y_MOD):
        tid = location_id(x, y + dy)
        if tid != 0 and tid not in taken:
            return tid
    raise RuntimeError("no free tower id")  # pragma: no cover - 1e8 ids taken at one x


def assign_ids(
    footprints: Sequence[Any], registry: gpd.GeoDataFrame | None, max_dist: float = MATCH_DISTANCE
) -> tuple[np.ndarray, list[Any], list[str]]:
    """Ids of towers: a registered tower's where they match it, else a new location id.

    Parameters
    ----------
    footprints
        Footprint polygons of the towers (one job's towers: those it reports and those
        of its neighbours it reaches into).
    registry
        :func:`towerpipe.products.registry_file.read_registry`'s table (``None`` or empty: every
        tower is new).
    max_dist
        Centroid distance (m) of a match when the footprints do not intersect.

    Returns
    -------
    ids
        ``(n,)`` int64.
    first_seen
        Registered ``first_seen`` per tower (``None`` for a new one).
    review_status
        Registered review status per tower (:data:`REVIEW_DEFAULT` for a new one).
    """
    from towerpipe.towers.matching import match_towers

    n = len(footprints)
    ids = np.zeros(n, dtype=np.int64)
    first: list[Any] = [None] * n
    review = [REVIEW_DEFAULT] * n
    if n == 0:
        return ids, first, review
    geoms = gpd.GeoSeries(list(footprints))
    reg = registry if registry is not None and len(registry) else None
    if reg is not None:
        pred = gpd.GeoDataFrame({"tower_id": [str(i) for i in range(n)]}, geometry=geoms.values)
        truth = gpd.GeoDataFrame({"tower_id": [str(int(v)) for v in reg["tower_id"]]}, geometry=reg.geometry.values)
        rows = {str(int(v)): i for i, v in enumerate(reg["tower_id"])}
        for m in match_towers(pred, truth, max_dist=max_dist)["matches"]:
            i, r = int(m["pred"]), rows[m["truth"]]
            ids[i] = int(reg["tower_id"].iloc[r])
            first[i] = reg["first_seen"].iloc[r]
            review[i] = str(reg["review_status"].iloc[r] or REVIEW_DEFAULT)
    taken = set(ids[ids > 0].tolist()) | (set(int(v) for v in reg["tower_id"]) if reg is not None else set())
    cent = geoms.centroid
    # new ids in a fixed order (by location), so every job derives the same ones
    for i in sorted(np.flatnonzero(ids == 0).tolist(), key=lambda k: (cent.iloc[k].x, cent.iloc[k].y)):
        ids[i] = _free_id(cent.iloc[i].x, cent.iloc[i].y, taken)
        taken.add(int(ids[i]))
    return ids, first, review


def unique_ids(towers: gpd.GeoDataFrame) -> gpd.GeoDataFrame:
    """The zone's towers with each id once.

    Two blocks give one id to two towers only when both matched the same registered
    tower in their own jobs (two towers within a few metres of it, on either side of a
    block edge): the tower nearer to where the id was made keeps it, the other gets a new
    id (its points in its classified block keep the first id until that block reruns),
    with a warning.
    """
    if not len(towers) or towers["tower_id"].is_unique:
        return towers
    out = towers.copy().reset_index(drop=True)
    taken = set(int(v) for v in out["tower_id"])
    for tid, group in out.groupby("tower_id", sort=True):
        if len(group) < 2:
            continue
        x0, y0 = (int(tid) // _Y_MOD, int(tid) % _Y_MOD)
        dist = np.hypot(group["centroid_x"] % _X_MOD - x0, group["centroid_y"] % _Y_MOD - y0)
        for i in group.index[np.argsort(dist.to_numpy(), kind="stable")][1:]:
            new = _free_id(out.at[i, "centroid_x"], out.at[i, "centroid_y"], taken)
            taken.add(new)
            log.warning(
                "tower id %d given to two towers (blocks %s and %s): the one at (%.1f, %.1f) becomes %d",
                tid,
                group["block"].iloc[0],
                out.at[i, "block"],
                out.at[i, "centroid_x"],
                out.at[i, "centroid_y"],
                new,
            )
            out.at[i, "tower_id"] = new
    return out.sort_values("tower_id", kind="stable").reset_index(drop=True)


# --------------------------------------------------------------------------- the registry
def empty_registry(crs: Any = None) -> gpd.GeoDataFrame:
    return empty_frame(REGISTRY_FIELDS, crs)


def update_registry(
    registry: gpd.GeoDataFrame,
    towers: gpd.GeoDataFrame,
    *,
    run_time: Any,
    keep_blocks: Iterable[str] = (),
    reviews: Mapping[int, str] | None = None,
) -> gpd.GeoDataFrame:
    """The registry after an assembly.

    Parameters
    ----------
    registry
        The registry before (:func:`towerpipe.products.registry_file.read_registry`).
    towers
        Every tower of the zone now (``tower_id``, ``block``, ``centroid_x``,
        ``centroid_y``, ``height_m``, ``first_seen``, footprint).
    run_time
        Time of the assembly (``last_seen`` of the towers found, ``vanished_since`` of
        those newly not found).
    keep_blocks
        Blocks whose towers are unknown this time (their jobs failed): their registered
        towers are left as they were, not marked vanished.
    reviews
        ``tower_id`` → review status edited by analysts in the published products since
        the last run (:func:`towerpipe.products.registry_file.published_reviews`); applied to
        registered towers.

    Returns
    -------
    geopandas.GeoDataFrame
        :data:`REGISTRY_FIELDS`, sorted by ``tower_id``.
    """
    run_time = (
        pd.Timestamp(run_time).tz_convert("UTC") if pd.Timestamp(run_time).tzinfo else pd.Timestamp(run_time, tz="UTC")
    )
    crs = towers.crs if towers.crs is not None else registry.crs
    reg = registry.set_index("tower_id", drop=False) if len(registry) else None
    rows, geoms = [], []
    found = set()
    for t in towers.itertuples(index=False):
        tid = int(t.tower_id)
        found.add(tid)
        old = reg.loc[tid] if reg is not None and tid in reg.index else None
        review = getattr(t, "review_status", None) or (old["review_status"] if old is not None else REVIEW_DEFAULT)
        first = (
            old["first_seen"]
            if old is not None and pd.notna(old["first_seen"])
            else (getattr(t, "first_seen", None) if pd.notna(getattr(t, "first_seen", None)) else run_time)
        )
        rows.append(
            {
                "tower_id": tid,
                "status": ACTIVE,
                "block": t.block,
                "centroid_x": t.centroid_x,
                "centroid_y": t.centroid_y,
                "height_m": t.height_m,
                "first_seen": first,
                "last_seen": run_time,
                "vanished_since": pd.NaT,
                "review_status": review,
            }
        )
        geoms.append(t.geometry)
    keep = set(keep_blocks)
    for r in registry.itertuples(index=False) if len(registry) else ():
        tid = int(r.tower_id)
        if tid in found:
            continue
        row = {k: getattr(r, k) for k in REGISTRY_FIELDS}
        if r.status == ACTIVE and r.block not in keep:
            row.update(status=VANISHED, vanished_since=run_time)
        rows.append(row)
        geoms.append(r.geometry)
    if not rows:
        return empty_registry(crs)
    out = gpd.GeoDataFrame(rows, geometry=geoms, crs=crs)
    for tid, status in (reviews or {}).items():
        if status in REVIEW_STATUSES:
            out.loc[out["tower_id"] == int(tid), "review_status"] = status
    return conform(out.sort_values("tower_id", kind="stable"), REGISTRY_FIELDS, crs)


def vanished(registry: gpd.GeoDataFrame) -> gpd.GeoDataFrame:
    """The registered towers not found by the last assembly."""
    if not len(registry):
        return registry
    return registry[registry["status"] == VANISHED].reset_index(drop=True)
