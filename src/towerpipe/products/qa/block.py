"""The QA page of one block: :func:`block_report`.

:func:`block_report` gathers the numbers of one block (points per stage, ground,
density, HAG, windows, towers, timings and memory, sensor attributes, accuracy against
input labels when there are any), decides whether the block needs a human look (see
:class:`towerpipe.products.qa.metrics.Limits`), and writes

* ``out_html``: the page (template ``block.html``), inline CSS and embedded PNG
  figures (no external assets: it can be mailed or opened from a network share), with
  relative links to the zone index and the block's products in ``results/<zone>/``;
* ``out_json``: every number on the page, read by :func:`towerpipe.products.qa.index.zone_index`.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe import classes
from towerpipe.io.atomic import write_text_atomic
from towerpipe.products import layout
from towerpipe.products.qa.delivery_classes import user_class_rows, user_classes
from towerpipe.products.qa.metrics import (
    Limits,
    data_extent,
    density_grid,
    distance_to_data_edge,
    jsonable,
    label_accuracy,
    load_classified,
    point_chunks,
    read_benchmark,
    read_towers,
    sum_dicts,
    tower_flag_reason,
)
from towerpipe.products.qa.pages import render
from towerpipe.products.qa.plots import block_map, density_map, hag_histogram, max_z_grid, raster_grid, tower_elevations
from towerpipe.progress import Progress

log = logging.getLogger(__name__)


def _links(block: str) -> list[dict[str, str]]:
    here = layout.block_product(layout.QA_PAGE, block)
    return [
        {"label": f"← {label}", "href": layout.link(here, target)}
        if i == 0
        else {"label": label, "href": layout.link(here, target)}
        for i, (label, target) in enumerate(
            (
                ("zone index", layout.QA_INDEX),
                (
                    f"classified points ({Path(layout.BLOCK_LAZ).name.format(block=block)})",
                    layout.block_product(layout.BLOCK_LAZ, block),
                ),
                ("block towers (GeoPackage)", layout.block_product(layout.BLOCK_GPKG, block)),
                ("zone towers (GeoPackage)", layout.ZONE_GPKG),
            )
        )
    ]


def _summary(n_towers: int, n_look_towers: int, flags: list[dict[str, str]]) -> str:
    s = f"{n_towers} tower{'s' if n_towers != 1 else ''} found"
    if n_look_towers:
        s += f"; {n_look_towers} need{'s' if n_look_towers == 1 else ''} a look"
    other = [f["reason"] for f in flags if f["code"] != "tower"]
    if other:
        s += "; block needs a look: " + "; ".join(other)
    elif not flags:
        s += "; nothing to check"
    return s + "."


@dataclass(frozen=True)
class BlockInputs:
    """What the QA page of one block is made from (:func:`block_report`).

    Attributes
    ----------
    block_name, zone
        Names shown on the page.
    block_bounds
        ``(xmin, ymin, xmax, ymax)`` of the block (default: the points' extent).
    stats
        The block's preprocessing summary or any further numbers: kept in the JSON and
        shown folded as raw metadata. Its ``attributes`` / ``degenerate_attributes``
        (sensor-attribute validity, when the split recorded it) get a table and a flag.
    tile_metas, pred_metas
        ``meta`` dicts of the block's tile files and prediction files (counts,
        ``ground_source``, windows, timings, ``peak_rss_mb``, model and its ``choice``).
    towers
        The block's towers: GeoDataFrame from :func:`towerpipe.towers.extract.extract_towers`
        or the path of the block's tower GeoPackage.
    classified
        The classified points (mapping with ``x, y, z, classification`` and
        optionally ``prob``, ``hag``) or the path of the classified LAZ.
    raster
        A DTM/DSM GeoTIFF for the hillshade (default: max z of the points per cell).
    truth
        Input class labels of the points (Classification before it was
        overwritten), same order as ``classified``; towers are class 15. When it
        holds class 15, tower precision/recall and point IoU are reported.
    truth_points
        ``x, y, z, hag`` of the labelled tower points of the block's tiles, core and buffer
        (:func:`towerpipe.io.tiles.labelled_points`): the labelled towers are built from them,
        whole across the block's edges (default: from the block's labelled points).
    tower_points_here
        ``tower_id`` → points of this block classified 15 as that tower's, for every tower with
        points here, the neighbours' too (:func:`towerpipe.io.members.member_counts`): the class-15
        points of towers a neighbour owns are counted apart.
    timings
        Stage name → seconds, or → path of a Snakemake benchmark TSV (``s``, ``max_rss``).
    warnings
        Messages to show (e.g. logged warnings of the block's jobs).
    neighbour_towers
        Towers with points in this block that a neighbouring block owns (``tower_id``,
        ``footprint_wkt``): a labelled tower they match counts as found (recall), not as
        a tower of this block (precision).
    data_bounds
        Boxes of the block and of each neighbour that gave points: a tower whose
        footprint reaches the edge of their union may be cut and is flagged (default:
        the block alone). A tower across a seam between blocks that both gave points
        is whole and is not flagged.
    neighbourhoods
        ``tower_id`` → the points around the tower
        (:func:`towerpipe.products.qa.neighbourhoods.tower_neighbourhoods`): two
        side views per tower.
    """

    block_name: str
    zone: str = ""
    block_bounds: Sequence[float] | None = None
    stats: Mapping[str, Any] | None = None
    tile_metas: Sequence[Mapping[str, Any]] = ()
    pred_metas: Sequence[Mapping[str, Any]] = ()
    towers: Any = None
    classified: str | os.PathLike[str] | Mapping[str, np.ndarray] | None = None
    raster: str | os.PathLike[str] | None = None
    truth: np.ndarray | None = None
    truth_points: Mapping[str, np.ndarray] | None = None
    tower_points_here: Mapping[int, int] | None = None
    timings: Mapping[str, float | str | os.PathLike[str] | Mapping[str, Any]] | None = None
    warnings: Sequence[str] = ()
    neighbour_towers: Sequence[Mapping[str, Any]] | None = None
    data_bounds: Sequence[Sequence[float]] | None = None
    neighbourhoods: Mapping[str, Mapping[str, np.ndarray]] | None = None


def block_report(
    out_html: str | os.PathLike[str],
    out_json: str | os.PathLike[str],
    inputs: BlockInputs,
    limits: Limits,
) -> dict[str, Any]:
    """Write the QA page and its JSON for one block.

    Parameters
    ----------
    out_html, out_json
        Destinations (written atomically).
    inputs
        The block's numbers, towers and points.
    limits
        What flags the block or a tower for a look (:meth:`Limits.from_config`).

    Returns
    -------
    dict
        The numbers written to ``out_json`` (``status`` is ``"ok"`` or ``"look"``,
        ``flags`` lists the reasons).
    """
    block_name, tile_metas, pred_metas, raster = inputs.block_name, inputs.tile_metas, inputs.pred_metas, inputs.raster
    block_bounds, warnings = inputs.block_bounds, inputs.warnings
    out_html, out_json = Path(out_html), Path(out_json)
    gdf = read_towers(inputs.towers)
    pts = load_classified(inputs.classified) if inputs.classified is not None else None
    stats = dict(inputs.stats or {})
    flags: list[dict[str, str]] = []

    def flag(code: str, reason: str) -> None:
        flags.append({"code": code, "reason": reason})

    # ---- extent
    if block_bounds is None:
        cb = [m.get("core_bounds") for m in tile_metas if m.get("core_bounds")]
        if cb:
            arr = np.asarray(cb, dtype=float)
            block_bounds = [arr[:, 0].min(), arr[:, 1].min(), arr[:, 2].max(), arr[:, 3].max()]
        elif pts is not None and len(pts["x"]):
            x, y = np.asarray(pts["x"]), np.asarray(pts["y"])
            block_bounds = [x.min(), y.min(), x.max(), y.max()]
    bounds = [float(v) for v in block_bounds] if block_bounds is not None else None
    area_m2 = (bounds[2] - bounds[0]) * (bounds[3] - bounds[1]) if bounds else None

    # ---- points and ground
    tile_counts = sum_dicts(m.get("counts") for m in tile_metas)
    ground_sources = sorted({str(m.get("ground_source")) for m in tile_metas if m.get("ground_source")})
    ground_classified = any(s != "class2" for s in ground_sources)
    n_points = int(len(pts["x"])) if pts is not None else None
    cls = pts["classification"] if pts is not None else None
    # the ground the pipeline used (class 2, or PDAL's when it had to classify), else class 2
    n_ground = (
        int(tile_counts["ground_core"])
        if "ground_core" in tile_counts
        else int(np.count_nonzero(cls == classes.GROUND))
        if cls is not None
        else None
    )
    n_tower_pts = int(np.count_nonzero(cls == classes.TOWER)) if cls is not None else None
    ground_ratio = (n_ground / n_points) if n_points else None
    if ground_classified:
        flag(
            "ground_classified",
            f"input had no usable ground class; ground classified by towerpipe "
            f"({', '.join(s for s in ground_sources if s != 'class2')})",
        )
    if ground_ratio is not None and ground_ratio < limits.min_ground_ratio:
        flag("low_ground", f"only {100 * ground_ratio:.1f} % of points are ground")

    # ---- sensor attributes (recorded by the split when it checks them)
    attributes = stats.get("attributes") or {}
    degenerate = list(stats.get("degenerate_attributes") or [])
    if degenerate:
        flag(
            "degenerate_attributes",
            "sensor attributes unusable: "
            + "; ".join(f"{a} ({(attributes.get(a) or {}).get('reason', 'degenerate')})" for a in degenerate),
        )

    # ---- windows, model
    win = {
        k: int(sum(int(m.get(k) or 0) for m in pred_metas))
        for k in ("windows_total", "windows_passed_gate", "windows_segmented")
    }
    gate_ratio = win["windows_passed_gate"] / win["windows_total"] if win["windows_total"] else None
    if gate_ratio is not None and gate_ratio > limits.max_gate_ratio:
        flag(
            "many_windows_gated",
            f"{100 * gate_ratio:.0f} % of windows passed the classifier gate (> {100 * limits.max_gate_ratio:.0f} %)",
        )
    model = next((m.get("model") for m in pred_metas if m.get("model")), None) or {}
    wire_sources = sorted({str(m["wire_source"]) for m in pred_metas if m.get("wire_source")})  # infer.wire_source
    if wire_sources == ["detected"] and len(gdf):
        flag(
            "wires_detected",
            "no point of the delivery is classified as wire (13/14): the wire detector "
            "alone tells conductors from towers; look for pieces of conductor among the towers",
        )
    points_model_input = int(sum(int(m.get("points_model_input_core") or 0) for m in pred_metas))

    # ---- per-stage counts
    stage_counts: list[tuple[str, int]] = []
    if stats.get("noise_points") is not None:  # the split's noise (blocks split before 0.12.0 lack it)
        noise_classes = ", ".join(str(c) for c in stats.get("noise_classes") or []) or "none"
        stage_counts += [
            (f"input: noise classes ({noise_classes}) or withheld, left out", int(stats["noise_points"])),
            ("… of them withheld (LAS flag)", int(stats.get("withheld_points") or 0)),
        ]
    input_rows = len(stage_counts)  # the delivery's own classes go after them, once heights are known
    stage_counts += [(f"tiles: {k.replace('_', ' ')}", int(v)) for k, v in tile_counts.items()]
    if pred_metas:
        stage_counts.append(("model input (core points)", points_model_input))
    if n_points is not None:
        stage_counts += [
            ("output: all points", n_points),
            ("output: ground (class 2)", n_ground),
            ("output: tower (class 15)", n_tower_pts),
        ]
        here = inputs.tower_points_here or {}
        own = {str(t) for t in gdf["tower_id"]} if len(gdf) else set()  # as text: a caller may give text ids
        lent = {t: n for t, n in sorted(here.items()) if str(t) not in own}
        if lent:  # a tower across the seam: its points here carry the id the neighbour reports it under
            ids = ", ".join(str(t) for t in list(lent)[:5]) + (", …" if len(lent) > 5 else "")
            stage_counts.append((f"… of them in towers a neighbouring block reports ({ids})", sum(lent.values())))
    stage_counts.append(("towers", int(len(gdf))))

    # ---- figures and density
    figures: list[dict[str, str]] = []
    density: dict[str, Any] = {}
    if pts is not None and n_points and bounds:
        grid, density = density_grid(pts["x"], pts["y"], bounds)
        density["mean"] = n_points / area_m2 if area_m2 else None
        figures.append(
            {
                "src": density_map(grid, bounds, density["density_cell_m"]),
                "caption": "Point density: look for stripes, holes and low-density corners",
            }
        )
        if density["density_median"] < limits.min_density:
            flag("low_density", f"median density {density['density_median']:.1f} pts/m² (< {limits.min_density:.1f})")
    hag = None
    hag_source = None
    if pts is not None and "hag" in pts:
        hag, hag_source = np.asarray(pts["hag"], dtype=np.float64), "HAG of the pipeline"
    elif pts is not None and raster is not None:
        import rasterio

        with rasterio.open(raster) as ds:
            inv = ~ds.transform
            dtm = ds.read(1, masked=True).astype(np.float64).filled(np.nan)
        hag, hag_source = np.empty(len(pts["z"])), "z − the block's DTM"
        for s in point_chunks(len(hag)):  # no temporary of the block's size
            # rasterio.transform.rowcol's maths (floor of the inverse transform), without
            # its (3, n) stacking: a tenth of its time on 10 M points
            x, y = np.asarray(pts["x"][s], dtype=np.float64), np.asarray(pts["y"][s], dtype=np.float64)
            rows = np.clip(np.floor(inv.d * x + inv.e * y + inv.f), 0, dtm.shape[0] - 1).astype(np.int64)
            cols = np.clip(np.floor(inv.a * x + inv.b * y + inv.c), 0, dtm.shape[1] - 1).astype(np.int64)
            hag[s] = pts["z"][s] - dtm[rows, cols]
    user = user_classes(cls, hag) if cls is not None else {}
    stage_counts[input_rows:input_rows] = user_class_rows(user)
    if hag is not None:
        figures.append(
            {
                "src": hag_histogram(hag, cls == classes.TOWER if cls is not None else None),
                "caption": f"Height above ground ({hag_source}) of every point of the classified block, the "
                "noise classes (7, 18) included; the axis starts at the lowest point and ends at the 99.9th "
                "percentile or the highest tower point, higher points count in the last bar",
            }
        )
    if raster is not None:
        grid, gb, cell = raster_grid(raster)
        map_src = "the block's DTM"
    elif pts is not None and n_points and bounds:
        grid, cell = max_z_grid(*(np.asarray(pts[k]) for k in ("x", "y", "z")), bounds)
        gb, map_src = bounds, "max point z per cell"
    else:
        grid, gb, cell, map_src = None, None, 1.0, "nothing (no points given)"
    map_png = block_map(gdf, bounds, grid, gb, cell, map_src) if (bounds or len(gdf)) else None

    # ---- towers
    extent = data_extent(inputs.data_bounds if inputs.data_bounds is not None else ([bounds] if bounds else []))
    tower_rows = []
    views: dict[int, str] = {}
    progress = Progress(f"qa {block_name}: side views", len(gdf), "towers", logger=log)
    for i, r in enumerate(gdf.itertuples(index=False), 1):
        to_edge = distance_to_data_edge(r.geometry, extent)
        support = float(getattr(r, "wire_support", float("nan")))
        tflags = limits.tower_flags(r, to_edge, support_measured="wire_support" in gdf.columns)
        for t in tflags:
            flag("tower", tower_flag_reason(i, r.tower_id, t))
        tower_rows.append(
            {
                "n": i,
                "tower_id": r.tower_id,
                "x": r.centroid_x,
                "y": r.centroid_y,
                "height_m": r.height_m,
                "base_z": r.base_z,
                "n_points": int(r.n_points),
                "prob_mean": r.prob_mean,
                "prob_max": r.prob_max,
                "shape_score": float(getattr(r, "shape_score", float("nan"))),
                "shape_view": getattr(r, "shape_view", None),
                "wire_support": support,
                "blocks": r.blocks,
                "edge_distance_m": r.edge_distance_m,
                "data_edge_m": round(to_edge, 2) if math.isfinite(to_edge) else None,
                "flags": tflags,
            }
        )
        hood = (inputs.neighbourhoods or {}).get(r.tower_id)
        if hood is not None and len(hood["x"]):
            views[i] = tower_elevations(
                hood, (r.centroid_x, r.centroid_y), f"Tower {i} ({r.tower_id}), {r.height_m:.1f} m"
            )
        progress.update()
    progress.close()

    # ---- accuracy against input labels
    accuracy = None
    if inputs.truth is not None and pts is not None:
        accuracy = label_accuracy(
            pts,
            inputs.truth,
            gdf,
            bounds,
            min_truth_points=int(limits.min_truth_points),
            mast_prominence=float(limits.mast_prominence),
            neighbour_towers=inputs.neighbour_towers,
            truth_points=inputs.truth_points,
        )
        if accuracy is not None:
            if accuracy["recall"] is not None and accuracy["recall"] < limits.min_recall:
                flag(
                    "missed_towers",
                    f"{accuracy['fn']} of {accuracy['towers_true']} labelled towers not found "
                    f"(recall {accuracy['recall']:.2f})",
                )
            labelled, caught = accuracy["points_true"], accuracy["points_both"]
            if labelled >= limits.min_truth_points and caught < limits.min_point_recall * labelled:
                # also a labelled tower across the edge that the neighbour owning it missed: no
                # tower of this block's own to count in the recall above
                flag(
                    "missed_tower_points",
                    f"{labelled - caught} of the {labelled} points labelled {classes.TOWER} here are in no reported "
                    f"tower ({caught / labelled:.0%} found)",
                )
            if accuracy["precision"] is not None and accuracy["precision"] < limits.min_precision:
                flag(
                    "false_towers",
                    f"{accuracy['fp']} of {len(gdf)} towers found match no labelled tower "
                    f"(precision {accuracy['precision']:.2f})",
                )

    # ---- timings and memory
    stage_time: list[dict[str, Any]] = []
    for label, metas in (("preprocess (tiles)", tile_metas), ("inference (tiles)", pred_metas)):
        for k, v in sum_dicts(m.get("timings") for m in metas).items():
            stage_time.append({"stage": f"{label}: {k}", "seconds": float(v), "max_rss_mb": None})
    rss = [float(m["peak_rss_mb"]) for m in pred_metas if m.get("peak_rss_mb") is not None]
    if rss:
        stage_time.append({"stage": "inference: peak of tile jobs", "seconds": None, "max_rss_mb": max(rss)})
    for name, v in (inputs.timings or {}).items():
        if isinstance(v, (str, os.PathLike)):
            try:
                b = read_benchmark(v)
            except OSError as exc:
                warnings = [*warnings, f"benchmark file of {name} unreadable: {exc}"]
                continue
            stage_time.append({"stage": name, "seconds": b.get("seconds"), "max_rss_mb": b.get("max_rss_mb")})
        elif isinstance(v, Mapping):  # aggregated over several jobs: {"seconds", "max_rss_mb", "jobs"}
            label = f"{name} ({v['jobs']} jobs)" if v.get("jobs", 1) > 1 else name
            stage_time.append({"stage": label, "seconds": v.get("seconds"), "max_rss_mb": v.get("max_rss_mb")})
        else:
            stage_time.append({"stage": name, "seconds": float(v), "max_rss_mb": None})
    warnings = [str(w) for w in warnings]
    if warnings:
        flag("warnings", f"{len(warnings)} warning(s) during processing")

    status = "look" if flags else "ok"
    n_look_towers = sum(1 for t in tower_rows if t["flags"])
    doc = {
        "block": block_name,
        "zone": inputs.zone,
        "status": status,
        "summary": _summary(len(gdf), n_look_towers, flags),
        "flags": flags,
        "html": out_html.name,
        "generated_at": datetime.now(UTC).replace(microsecond=0).isoformat(),
        "bounds": bounds,
        "area_m2": area_m2,
        "points": n_points,
        "points_ground": n_ground,
        "points_tower": n_tower_pts,
        "ground_ratio": ground_ratio,
        "ground_sources": ground_sources,
        "ground_classified": ground_classified,
        "wire_sources": wire_sources,
        "density": density,
        "stage_counts": dict(stage_counts),
        "user_classes": user,
        "tile_counts": tile_counts,
        "attributes": attributes,
        "degenerate_attributes": degenerate,
        "tiles": len(tile_metas),
        "pred_files": len(pred_metas),
        **win,
        "gate_ratio": gate_ratio,
        "points_model_input": points_model_input if pred_metas else None,
        "model": {k: model.get(k) for k in ("name", "version", "feature_set", "sha256", "choice") if k in model},
        "towers": tower_rows,
        "n_towers": len(gdf),
        "tower_prob_mean": float(gdf["prob_mean"].mean()) if len(gdf) else None,
        "accuracy": accuracy,
        "timings": stage_time,
        "timings_total": sum(t["seconds"] or 0 for t in stage_time if ":" not in t["stage"]),
        "warnings": warnings,
        "stats": stats,
        "limits": dataclasses.asdict(limits),
    }
    doc = jsonable(doc)
    write_text_atomic(out_json, json.dumps(doc, indent=1))
    render(
        "block.html",
        out_html,
        d=doc,
        map_png=map_png,
        figures=figures,
        views=views,
        links=_links(block_name),
        json_name=out_json.name,
    )
    return doc
