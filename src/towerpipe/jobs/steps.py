"""One function per block or tile job that combines several library calls.

The scripts in ``workflow/scripts/`` call exactly one function each, from here
or from the module that owns the concept (:mod:`towerpipe.preprocess.split`,
:mod:`towerpipe.inference.infer`, :mod:`towerpipe.products.merge`); the zone's
publication is in :mod:`towerpipe.jobs.zone`, the trained model's in
:mod:`towerpipe.jobs.training`.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from towerpipe import classes
from towerpipe.io.atomic import write_text_atomic
from towerpipe.io.blockcache import BlockCache
from towerpipe.io.columns import read_meta

if TYPE_CHECKING:
    from towerpipe.config import InferenceConfig, PreprocessConfig
    from towerpipe.products.qa.metrics import Limits

log = logging.getLogger(__name__)


def _json(path: str | os.PathLike[str]) -> dict[str, Any]:
    return json.loads(Path(path).read_text())


def towers_step(
    zone: str,
    block: str,
    block_bounds: Sequence[float],
    preds: Sequence[str],
    out_gpkg: str | os.PathLike[str],
    *,
    towers_cfg: Mapping[str, Any],
    source_files: Mapping[str, str],
    run_cfg: Mapping[str, Any],
    point_threshold: float | None,
    out_neighbours: str | os.PathLike[str] | None = None,
    tile_files: Sequence[str] = (),
    wire_files: Sequence[str] = (),
    out_members: str | os.PathLike[str] | None = None,
    survey: Sequence[Sequence[float]] = (),
    registry: Sequence[str] = (),
    cache_dir: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Towers owned by ``block`` (from its and its neighbours' predictions) → GeoPackage.

    ``cache_dir`` is the block's split: a block that could not be read (its cache records the
    error) raises that :class:`~towerpipe.errors.InputError` here, its first job after the
    split (its neighbours went on without it).
    ``out_neighbours`` (JSON) receives the towers with points in the block that a
    neighbour owns (see :func:`towerpipe.towers.extract.extract_towers`), for the block's QA.
    ``tile_files`` (the block's and its neighbours' tiles) give the conductor support of
    each tower (:class:`towerpipe.towers.coverage.TileContext`); ``wire_files`` (the block's
    conductor-points files, :func:`infer_step`) its layer ``conductor_points``, from which
    the zone builds its lines; ``out_members``
    receives the points of every accepted tower with points in the block, owned or not
    (:func:`towerpipe.io.members.save_members`): the merge classifies them 15 and writes
    their tower id. ``survey`` (measured bounds of the block and its neighbours) and
    ``towers_cfg["wire_line_coverage"]`` leave the support of a tower unknown where a line
    through it could leave it outside the data. ``registry`` lists where the zone's tower registry
    may be, first found first (:func:`towerpipe.products.registry_file.read_registry`): matched towers
    keep their ids.
    """
    import geopandas as gpd

    from towerpipe.config import TowersConfig
    from towerpipe.errors import ModelError
    from towerpipe.io.conductors import load_conductors
    from towerpipe.io.members import save_members
    from towerpipe.io.predictions import load_pred
    from towerpipe.products.gpkg import run_metadata, write_towers_gpkg
    from towerpipe.products.registry_file import read_registry
    from towerpipe.towers.coverage import TileContext
    from towerpipe.towers.extract import extract_towers
    from towerpipe.towers.shape import resolve_verifier

    if cache_dir is not None:
        BlockCache.open(cache_dir)
    rules = TowersConfig.from_config({"towers": towers_cfg})
    line_share = float(towers_cfg["wire_line_coverage"])
    loaded = [load_pred(p) for p in preds]
    for p in loaded:  # an inference that could not run on a tile (infer_step recorded why)
        if p.meta.get("error"):
            if p.meta.get("block") == block:
                raise ModelError(p.meta["error"])
            log.warning("neighbour block %s: no predictions (%s)", p.meta.get("block"), p.meta["error"])
    own = [p for p in loaded if p.meta.get("block") == block] or loaded
    model_meta = own[0].meta.get("model") if own else None
    crs_wkt = own[0].meta.get("crs_wkt") if own else None
    found = extract_towers(
        loaded,
        block,
        block_bounds,
        rules,
        zone=zone,
        model_meta=model_meta,
        source_files=source_files,
        crs=crs_wkt,
        point_threshold=point_threshold,
        context=TileContext(tile_files, survey=survey, min_line_share=line_share) if tile_files else None,
        registry=read_registry(*registry),
    )
    gdf, neighbours = found.towers, found.neighbours
    if out_members is not None:
        save_members(out_members, found.members)
    wires = load_conductors(wire_files)
    conductors = gpd.GeoDataFrame(
        {"block": [block] * len(wires["x"]), **{k: wires[k] for k in ("z", "hag", "direction_deg", "clearance_m")}},
        geometry=gpd.points_from_xy(wires["x"], wires["y"]),
        crs=crs_wkt,
    )
    verifier = resolve_verifier(str(towers_cfg.get("verifier", "shipped")))
    meta = run_metadata(
        model_meta=model_meta,
        config=run_cfg,
        zone=zone,
        block=block,
        bounds=[float(v) for v in block_bounds],
        # the shape check's verifier (rule 8): the zone's file takes it with the model's fields
        model_verifier=verifier.name if verifier is not None else "none",
    )
    write_towers_gpkg(out_gpkg, gdf, crs_wkt=crs_wkt, metadata=meta, conductors=conductors)
    if out_neighbours is not None:
        write_text_atomic(
            out_neighbours, json.dumps({"block": block, "towers_owned_by_neighbours": neighbours}, indent=1)
        )
    return {"towers": len(gdf), "towers_owned_by_neighbours": len(neighbours), "conductor_points": len(conductors)}


def infer_step(
    tile_path: str | os.PathLike[str],
    model: str | os.PathLike[str] | None,
    out_path: str | os.PathLike[str],
    settings: InferenceConfig,
    *,
    out_wires: str | os.PathLike[str] | None = None,
    **kw: Any,
) -> dict[str, Any]:
    """:func:`towerpipe.inference.infer.infer_tile`, a model that cannot run on the tile recorded, not raised.

    ``out_wires`` receives the tile's conductor points
    (:func:`towerpipe.towers.wires.tile_conductor_points`, :mod:`towerpipe.io.conductors`):
    the wire search needs only the tile, so it runs here, in the parallel per-tile jobs,
    rather than in the block's towers job; it does not depend on the model.

    A :class:`~towerpipe.errors.ModelError` (e.g. the model needs NIR and the block has
    none) becomes an empty prediction file whose ``meta["error"]`` says why: the
    neighbours' towers jobs, which read this tile's predictions for the towers across
    their edges, go on; the block's own towers job raises it (:func:`towers_step`). A
    block the model cannot run on thus costs only itself.
    """
    from towerpipe.errors import ModelError
    from towerpipe.inference.infer import infer_tile
    from towerpipe.io.conductors import save_conductors
    from towerpipe.io.predictions import PRED_ARRAYS, save_pred
    from towerpipe.io.tiles import load_tile
    from towerpipe.towers.wires import tile_conductor_points

    if out_wires is not None:  # the tile is read once, for the wire search and the inference
        t0 = time.perf_counter()
        if kw.get("tile") is None:
            kw["tile"] = load_tile(tile_path)
        wires = tile_conductor_points(kw["tile"].arrays)
        save_conductors(out_wires, wires, {k: kw["tile"].meta.get(k) for k in ("zone", "block", "tile")})
        log.info("conductor points: %d in %.1f s", len(wires["x"]), time.perf_counter() - t0)
    try:
        return infer_tile(tile_path, model, out_path, settings, **kw)
    except ModelError as exc:
        meta = read_meta(tile_path)
        log.error(
            "ModelError: %s; recorded in %s: the block fails at its towers step, its neighbours go on", exc, out_path
        )
        rec = {k: meta.get(k) for k in ("zone", "block", "tile", "blocks", "crs_wkt", "core_bounds")}
        rec.update(
            model={},
            windows_total=0,
            windows_passed_gate=0,
            windows_segmented=0,
            gate_threshold=settings.gate,
            combine=settings.combine,
            points_core=0,
            points_model_input_core=0,
            timings={},
            peak_rss_mb=0.0,
            error=str(exc),
        )
        save_pred(out_path, {k: np.zeros(0, d) for k, d in PRED_ARRAYS.items()}, rec)
        return rec


def tile_step(
    zone: str,
    block: str,
    tile: str,
    cache_dirs: Mapping[str, str | os.PathLike[str]],
    out_tile: str | os.PathLike[str],
    out_pred: str | os.PathLike[str],
    *,
    dtm_path: str | os.PathLike[str],
    preprocess: PreprocessConfig,
    inference: InferenceConfig,
    out_wires: str | os.PathLike[str],
    missing: Mapping[str, str | os.PathLike[str]] | None = None,
    model: str | os.PathLike[str] | None = None,
    **kw: Any,
) -> dict[str, Any]:
    """A tile of a zone with products, in one job: its preprocessing
    (:func:`towerpipe.preprocess.tile.prepare_tile`), written to ``out_tile`` for the block's towers
    and QA jobs, then its conductor points and its inference (:func:`infer_step`, ``kw``) on the
    tile in memory. One process and one read of the points less per tile than a preprocessing job
    and an inference job; the predictions are those of the written tile. ``model`` as in
    :func:`infer_step` (``None``: the zone's choice, ``kw["choice"]``).
    """
    from towerpipe.io.tiles import save_tile
    from towerpipe.preprocess.tile import prepare_tile

    t = prepare_tile(zone, block, tile, cache_dirs, dtm_path=dtm_path, settings=preprocess, missing=missing)
    return infer_step(out_tile, model, out_pred, inference, out_wires=out_wires, tile=save_tile(out_tile, t), **kw)


def classified_points(
    cache_dir: str | os.PathLike[str],
    pred_files: Sequence[str],
    block: str,
    threshold: float,
    member_files: Sequence[str] | None = None,
) -> dict[str, np.ndarray]:
    """The block's points as the merge step classifies them, from the decoded cache.

    ``x, y, z`` (read a chunk at a time: :class:`~towerpipe.io.blockcache.ColumnReader`), the
    output ``classification`` and ``prob``, as :func:`towerpipe.products.labels.block_labels`
    gives them to the merge step, so the QA does not decode the written LAZ a second time.
    """
    from towerpipe.products.labels import block_labels

    cache = BlockCache(cache_dir)
    cols: dict[str, Any] = {c: cache.reader(c) for c in ("x", "y", "z")}
    labels = block_labels(
        pred_files, len(cols["x"]), block=block, block_path=str(cache.directory), tower_points=member_files
    )
    cols["classification"] = labels.classes(np.asarray(cache.column("classification")), threshold)
    cols["prob"] = labels.prob
    return cols


def qa_step(
    zone: str,
    block: str,
    *,
    cache_dir: str,
    tile_files: Sequence[str],
    pred_files: Sequence[str],
    towers_gpkg: str,
    dtm_files: Sequence[str],
    benchmarks: Mapping[str, Sequence[str]],
    out_html: str,
    out_json: str,
    threshold: float,
    limits: Limits,
    neighbours_json: str | None = None,
    member_files: Sequence[str] | None = None,
    block_bounds: Mapping[str, Sequence[float]] | None = None,
) -> dict[str, Any]:
    """The block's QA page: preprocessing summary, gate counts, towers, side views, labels if any.

    The preprocessing summary is summed from the metadata of the block's cache and tiles
    (:func:`towerpipe.preprocess.tile.summarize_block`).
    ``limits`` (the config's ``qa`` section and four tower rules) flag the block or a tower
    for a look. ``block_bounds`` (block → header bounds, the block's and its neighbours') gives the
    edge of the data: a tower reaching it may be cut. Only the neighbours that gave
    points to the block's tiles count (a neighbour that failed did not).
    """
    from towerpipe.io.members import member_counts
    from towerpipe.io.tiles import labelled_points
    from towerpipe.preprocess.ground import mosaic_dtm
    from towerpipe.preprocess.tile import summarize_block
    from towerpipe.products.qa.block import BlockInputs, block_report
    from towerpipe.products.qa.metrics import read_benchmark, read_towers
    from towerpipe.products.qa.neighbourhoods import tower_neighbourhoods

    summary = summarize_block(cache_dir, tile_files)
    truth = None
    cls = BlockCache(cache_dir).column("classification")
    if summary.get("class_counts", {}).get(str(classes.TOWER)):
        truth = np.asarray(cls) == classes.TOWER
    timings: dict[str, Any] = {}
    for stage, tsvs in benchmarks.items():
        rows = [read_benchmark(t) for t in tsvs if Path(t).exists()]
        if rows:
            rss = [r["max_rss_mb"] for r in rows if "max_rss_mb" in r]
            timings[stage] = {
                "seconds": sum(r.get("seconds", 0.0) for r in rows),
                "max_rss_mb": max(rss) if rss else None,
                "jobs": len(rows),
            }
    tile_metas = [read_meta(p) for p in tile_files]
    data_bounds = None
    if block_bounds is not None:
        gave_points = {block} | {b for m in tile_metas for b in m.get("blocks") or []}
        data_bounds = [bb for b, bb in block_bounds.items() if b in gave_points and bb is not None]
    towers = read_towers(towers_gpkg)
    hoods = tower_neighbourhoods(tile_files, member_files or [], towers)
    with tempfile.TemporaryDirectory(prefix="towerpipe-qa-") as tmp:
        raster = mosaic_dtm(dtm_files, Path(tmp) / "dtm.tif")
        return block_report(
            out_html,
            out_json,
            BlockInputs(
                block_name=block,
                zone=zone,
                block_bounds=summary["bounds"],
                stats=summary,
                tile_metas=tile_metas,
                pred_metas=[read_meta(p) for p in pred_files],
                data_bounds=data_bounds,
                neighbourhoods=hoods,
                towers=towers,
                classified=classified_points(cache_dir, pred_files, block, threshold, member_files),
                raster=str(raster) if raster else None,
                truth=truth,
                # the labelled towers whole across the block's edges: a seam tower counts once
                truth_points=labelled_points(list(tile_files), classes.TOWER) if truth is not None else None,
                tower_points_here=member_counts(member_files, block, len(cls)) if member_files else None,
                timings=timings,
                warnings=summary.get("warnings", []),
                neighbour_towers=_json(neighbours_json)["towers_owned_by_neighbours"] if neighbours_json else None,
            ),
            limits,
        )
