"""One function per workflow job that combines several library calls.

The scripts in ``workflow/scripts/`` call exactly one function each, from here
or from the module that owns the concept (:mod:`towerpipe.preprocess.split`,
:mod:`towerpipe.inference.infer`, :mod:`towerpipe.products.merge`).
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from towerpipe import __version__, classes
from towerpipe.io.atomic import assemble_directory, publish_copy, write_text_atomic
from towerpipe.io.blockcache import BlockCache
from towerpipe.io.columns import read_meta
from towerpipe.model.cards import config_hash
from towerpipe.products import layout

if TYPE_CHECKING:  # geopandas is imported by the steps that need it: the DAG does not
    import geopandas as gpd

    from towerpipe.config import InferenceConfig

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
    out_members: str | os.PathLike[str] | None = None,
    survey: Sequence[Sequence[float]] = (),
    registry: Sequence[str] = (),
) -> dict[str, Any]:
    """Towers owned by ``block`` (from its and its neighbours' predictions) → GeoPackage.

    ``out_neighbours`` (JSON) receives the towers with points in the block that a
    neighbour owns (see :func:`towerpipe.towers.extract.extract_towers`), for the block's QA.
    ``tile_files`` (the block's and its neighbours' tiles) give the conductor support of
    each tower (:class:`towerpipe.towers.wires.TileContext`) and the block's conductor points
    (layer ``conductor_points``, from which the zone builds its lines); ``out_members``
    receives the points of every accepted tower with points in the block, owned or not
    (:func:`towerpipe.io.members.save_members`): the merge classifies them 15 and writes
    their tower id. ``survey`` (measured bounds of the block and its neighbours) and
    ``towers_cfg["wire_ring_coverage"]`` leave the support of a tower whose conductor ring
    is mostly outside the data unknown. ``registry`` lists where the zone's tower registry
    may be, first found first (:func:`towerpipe.products.registry_file.read_registry`): matched towers
    keep their ids.
    """
    import geopandas as gpd

    from towerpipe.config import TowersConfig
    from towerpipe.errors import ModelError
    from towerpipe.io.members import save_members
    from towerpipe.io.predictions import load_pred
    from towerpipe.products.gpkg import run_metadata, write_towers_gpkg
    from towerpipe.products.registry_file import read_registry
    from towerpipe.towers.extract import extract_towers
    from towerpipe.towers.wires import TileContext, conductor_points

    rules = TowersConfig.from_config({"towers": towers_cfg})
    ring_share = float(towers_cfg["wire_ring_coverage"])
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
        context=TileContext(tile_files, survey=survey, min_ring_share=ring_share) if tile_files else None,
        registry=read_registry(*registry),
    )
    gdf, neighbours = found.towers, found.neighbours
    if out_members is not None:
        save_members(out_members, found.members)
    wires = conductor_points(tile_files, block)
    conductors = gpd.GeoDataFrame(
        {"block": [block] * len(wires["x"]), **{k: wires[k] for k in ("z", "hag", "direction_deg", "clearance_m")}},
        geometry=gpd.points_from_xy(wires["x"], wires["y"]),
        crs=crs_wkt,
    )
    meta = run_metadata(
        model_meta=model_meta, config=run_cfg, zone=zone, block=block, bounds=[float(v) for v in block_bounds]
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
    **kw: Any,
) -> dict[str, Any]:
    """:func:`towerpipe.inference.infer.infer_tile`, a model that cannot run on the tile recorded, not raised.

    A :class:`~towerpipe.errors.ModelError` (e.g. the model needs NIR and the block has
    none) becomes an empty prediction file whose ``meta["error"]`` says why: the
    neighbours' towers jobs, which read this tile's predictions for the towers across
    their edges, go on; the block's own towers job raises it (:func:`towers_step`). A
    block the model cannot run on thus costs only itself.
    """
    from towerpipe.errors import ModelError
    from towerpipe.inference.infer import infer_tile
    from towerpipe.io.predictions import PRED_ARRAYS, save_pred

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


def classified_points(
    cache_dir: str | os.PathLike[str],
    pred_files: Sequence[str],
    block: str,
    threshold: float,
    member_files: Sequence[str] | None = None,
) -> dict[str, np.ndarray]:
    """The block's points as the merge step classifies them, from the decoded cache.

    ``x, y, z`` (memory-mapped), the output ``classification`` and ``prob``, as
    :func:`towerpipe.products.merge.block_labels` gives them to the merge step, so the QA
    does not decode the written LAZ a second time.
    """
    from towerpipe.products.merge import block_labels

    cache = BlockCache(cache_dir)
    cols = {c: cache.column(c) for c in ("x", "y", "z", "classification")}
    labels = block_labels(
        pred_files, len(cols["x"]), block=block, block_path=str(cache.directory), tower_points=member_files
    )
    cols["classification"] = labels.classes(np.asarray(cols["classification"]), threshold)
    cols["prob"] = labels.prob
    return cols


def qa_step(
    zone: str,
    block: str,
    *,
    summary_json: str,
    cache_dir: str,
    tile_files: Sequence[str],
    pred_files: Sequence[str],
    towers_gpkg: str,
    dtm_files: Sequence[str],
    benchmarks: Mapping[str, Sequence[str]],
    out_html: str,
    out_json: str,
    threshold: float,
    neighbours_json: str | None = None,
    member_files: Sequence[str] | None = None,
    block_bounds: Mapping[str, Sequence[float]] | None = None,
) -> dict[str, Any]:
    """The block's QA page: preprocessing summary, gate counts, towers, side views, labels if any.

    ``block_bounds`` (block → header bounds, the block's and its neighbours') gives the
    edge of the data: a tower reaching it may be cut. Only the neighbours that gave
    points to the block's tiles count (a neighbour that failed did not).
    """
    from towerpipe.preprocess.ground import mosaic_dtm
    from towerpipe.products.qa.block import BlockInputs, block_report, tower_neighbourhoods
    from towerpipe.products.qa.metrics import read_benchmark, read_towers

    summary = _json(summary_json)
    truth = None
    cls = BlockCache(cache_dir).column("classification")
    if summary.get("class_counts", {}).get(str(classes.TOWER)):
        truth = np.asarray(cls) == classes.TOWER
    timings: dict[str, Any] = {}
    for stage, tsvs in benchmarks.items():
        rows = [read_benchmark(t) for t in tsvs if Path(t).exists()]
        if rows:
            timings[stage] = {
                "seconds": sum(r.get("seconds", 0.0) for r in rows),
                "max_rss_mb": max(r.get("max_rss_mb", 0.0) for r in rows),
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
                timings=timings,
                warnings=summary.get("warnings", []),
                neighbour_towers=_json(neighbours_json)["towers_owned_by_neighbours"] if neighbours_json else None,
            ),
        )


def zone_towers(
    tower_gpkgs: Sequence[str],
    *,
    registry: gpd.GeoDataFrame,
    run_time: Any,
    keep_blocks: Sequence[str] = (),
    published: str | os.PathLike[str] | None = None,
    crs_wkt: str | None = None,
) -> dict[str, Any]:
    """The content of a zone's ``towers.gpkg`` and its new registry, from the blocks' GeoPackages.

    Towers of all blocks (each id once, :func:`towerpipe.towers.registry.unique_ids`), linked into
    lines by the blocks' conductor points (:func:`towerpipe.towers.lines.build_lines`, judged
    inside the blocks' bounds), the registry updated (:func:`towerpipe.towers.registry.update_registry`,
    with the review statuses analysts set in the ``published`` file) and its vanished towers.

    Returns
    -------
    dict
        ``towers``, ``lines``, ``spans``, ``vanished``, ``registry`` (GeoDataFrames), ``crs``
        and ``metadata`` (the first block's model fields).
    """
    import shapely

    from towerpipe.products.gpkg import LAYER_CONDUCTORS, concat_towers, list_layers, read_metadata
    from towerpipe.products.registry_file import published_reviews
    from towerpipe.towers.lines import build_lines
    from towerpipe.towers.registry import unique_ids, update_registry, vanished

    towers = unique_ids(concat_towers(tower_gpkgs, crs_wkt=crs_wkt))
    crs = towers.crs if towers.crs is not None else crs_wkt
    with_wires = [p for p in tower_gpkgs if LAYER_CONDUCTORS in list_layers(p)]
    wires = concat_towers(with_wires, LAYER_CONDUCTORS, crs_wkt=crs)
    conductors = {k: wires[k].to_numpy(float) for k in ("hag", "direction_deg", "clearance_m")} if len(wires) else {}
    if len(wires):
        conductors.update(x=wires.geometry.x.to_numpy(), y=wires.geometry.y.to_numpy())
    metas = [read_metadata(p) for p in tower_gpkgs]
    boxes = [shapely.box(*json.loads(m["bounds"])) for m in metas if m.get("bounds")]
    extent = shapely.union_all(boxes) if boxes and len(boxes) == len(metas) else None
    if len(towers):
        towers, lines, spans = build_lines(towers, conductors, extent=extent)
    else:
        lines = spans = None
    reviews = published_reviews(published, registry)
    new_registry = update_registry(registry, towers, run_time=run_time, keep_blocks=keep_blocks, reviews=reviews)
    if len(towers):
        status = dict(zip(new_registry["tower_id"], new_registry["review_status"]))
        towers["review_status"] = [status.get(t, r) for t, r in zip(towers["tower_id"], towers["review_status"])]
    model = {k: v for k, v in (metas[0] if metas else {}).items() if k.startswith("model_")}
    return {
        "towers": towers,
        "lines": lines,
        "spans": spans,
        "vanished": vanished(new_registry),
        "registry": new_registry,
        "crs": crs,
        "metadata": model,
    }


def zone_step(
    zone: str,
    out_dir: str,
    files: Mapping[str, str],
    *,
    tower_gpkgs: Sequence[str],
    qa_jsons: Sequence[str],
    failures: Mapping[str, str] | None = None,
    run_cfg: Mapping[str, Any] | None = None,
    stage_dir: str | os.PathLike[str] | None = None,
    manifest: str | os.PathLike[str] | None = None,
    sources: Mapping[str, str] | None = None,
    block_bounds: Mapping[str, Sequence[float] | None] | None = None,
    registry: str | os.PathLike[str] | None = None,
) -> Path:
    """Publish ``results/<zone>/``: per-block links, zone GeoPackage, QA index (+ ``INCOMPLETE.txt``).

    The zone is built in ``stage_dir`` (the last published zone, kept so that a deleted
    ``results/<zone>/`` can be restored without rebuilding) and ``out_dir`` is swapped in
    as a hard-linked copy of it (:func:`towerpipe.io.atomic.publish_copy`): it is never
    deleted first and exists at every moment. With ``failures`` the zone is INCOMPLETE:
    ``INCOMPLETE.txt`` is written before the swap. ``manifest`` (JSON, the workflow's
    record of the publication) lists the blocks, their original files and the failures.
    A zone where no block completed gets no GeoPackage (nothing to merge, no CRS).
    ``block_bounds`` (block → header bounds) places the failed blocks on the index's map.

    ``registry`` is the zone's tower registry file: read (or, when it is missing, the
    published GeoPackage), updated with this assembly's towers and written back once the
    directory is in place. Towers of ``failures`` blocks are left as they were.
    """
    from towerpipe.products.gpkg import write_towers_gpkg
    from towerpipe.products.qa.index import zone_index
    from towerpipe.products.registry_file import read_registry, write_registry

    run_time = datetime.now(UTC).replace(microsecond=0)
    failures = dict(failures or {})
    published = Path(str(out_dir).rstrip("/")) / layout.ZONE_GPKG
    content = None
    vanished_rows: list[dict[str, Any]] = []
    if tower_gpkgs:
        content = zone_towers(
            tower_gpkgs,
            registry=read_registry(registry, published),
            run_time=run_time,
            keep_blocks=list(failures),
            published=published,
        )
        vanished_rows = [
            {
                "tower_id": int(r.tower_id),
                "block": r.block,
                "centroid_x": r.centroid_x,
                "centroid_y": r.centroid_y,
                "height_m": r.height_m,
                "last_seen": r.last_seen.isoformat(),
                "vanished_since": r.vanished_since.isoformat(),
                "review_status": r.review_status,
            }
            for r in content["vanished"].itertuples()
        ]

    def build(tmp: Path) -> None:
        gpkg = tmp / layout.ZONE_GPKG
        if content is not None:
            crs = content["crs"]
            write_towers_gpkg(
                gpkg,
                content["towers"] if len(content["towers"]) else None,
                crs_wkt=crs.to_wkt() if hasattr(crs, "to_wkt") else crs,
                lines=content["lines"],
                spans=content["spans"],
                vanished=content["vanished"],
                metadata={
                    "zone": zone,
                    "towerpipe_version": __version__,
                    **content["metadata"],
                    "assembled_at": run_time.isoformat(),
                    "config_hash": config_hash(run_cfg or {}),
                    "blocks": str(len(tower_gpkgs)),
                    "n_towers": str(len(content["towers"])),
                    "n_lines": str(0 if content["lines"] is None else len(content["lines"])),
                },
            )
        index = tmp / layout.QA_INDEX
        index.parent.mkdir(parents=True, exist_ok=True)
        zone_index(
            index,
            [str(index.parent / Path(j).name) for j in qa_jsons],
            failures=failures,
            zone=zone,
            out_json=tmp / layout.QA_INDEX_JSON,
            gpkg=gpkg if content is not None else None,
            block_bounds=block_bounds,
            vanished=vanished_rows,
        )
        if failures:
            (tmp / "INCOMPLETE.txt").write_text(
                "This zone is INCOMPLETE: the run failed for these blocks (see qa/index.html):\n"
                + "".join(f"  {b}: {r}\n" for b, r in sorted(failures.items()))
                + "Fix the inputs (or remove them) and rerun the same snakemake command.\n"
            )

    stage = Path(stage_dir) if stage_dir is not None else None
    if stage is None:
        out = assemble_directory(out_dir, files, build)
    else:
        assemble_directory(stage, files, build)
        out = publish_copy(stage, out_dir)
    if registry is not None and content is not None and content["crs"] is not None:
        crs = content["crs"]
        write_registry(registry, content["registry"], crs.to_wkt() if hasattr(crs, "to_wkt") else crs)
    if manifest is not None:
        blocks = sorted({Path(rel).stem for rel in files if rel.startswith("blocks/")})
        write_text_atomic(
            manifest,
            json.dumps(
                {
                    "zone": zone,
                    "published": str(out),
                    "complete": not failures,
                    "published_at": datetime.now(UTC).isoformat(timespec="seconds"),
                    "blocks": {b: (sources or {}).get(b) for b in blocks},
                    "failures": failures,
                },
                indent=1,
            ),
        )
    return out


def model_results_step(bundle_dir: str, ablation_dirs: Sequence[str], out_dir: str) -> Path:
    """``results/models/<name>/``: checkpoint, card, curves, ``metrics.json`` (+ ablation), atomically."""
    files = {p.name: str(p) for p in sorted(Path(bundle_dir).iterdir()) if p.is_file()}
    for d in ablation_dirs:
        files.update({p.name: str(p) for p in sorted(Path(d).iterdir()) if p.is_file()})

    def build(tmp: Path) -> None:
        card = _json(Path(bundle_dir) / "model_card.json")
        (tmp / "metrics.json").write_text(json.dumps(card.get("metrics", {}), indent=1))

    return assemble_directory(out_dir, files, build)


def current_blocks(
    files: Mapping[str, str],
    caches: Mapping[str, str],
    fingerprints: Mapping[str, str],
    neighbours: Mapping[str, Sequence[str]] | None = None,
) -> tuple[set[str], dict[str, str]]:
    """Blocks whose products are those of their current input, and why the others are not.

    A block's products are current when they all exist, its split ran on the input's
    present content (the cache's fingerprint) without error, and none of them is older
    than its own or a neighbour's split (the buffers it used). Old products of a block
    whose input changed, or whose jobs failed, are therefore never republished as current.
    """
    by_block: dict[str, list[Path]] = {}
    for rel, src in files.items():
        by_block.setdefault(Path(rel).stem, []).append(Path(src))
    cache = {b: BlockCache(d) for b, d in caches.items()}

    def split_time(b: str) -> float | None:
        return cache[b].meta_path.stat().st_mtime if b in cache and cache[b].exists() else None

    ok: set[str] = set()
    why: dict[str, str] = {}
    for b, products in sorted(by_block.items()):
        if not all(p.exists() for p in products):
            why[b] = "not processed by this run (no products)"
            continue
        try:
            meta = cache[b].read_meta()
        except (KeyError, OSError, ValueError):
            why[b] = "not split by this run; its previous products are withheld"
            continue
        if meta.get("error") or (meta.get("source") or {}).get("fingerprint") != fingerprints.get(b):
            why[b] = "its input changed and was not processed; its previous products are withheld"
            continue
        made = min(p.stat().st_mtime for p in products)
        times = [t for t in (split_time(n) for n in [b, *(neighbours or {}).get(b, [])]) if t is not None]
        if times and made < max(times):
            why[b] = "its products are older than its input or its neighbours'; withheld until rerun"
            continue
        ok.add(b)
    return ok, why


def assemble_incomplete_zone(
    zone: str,
    out_dir: str,
    files: Mapping[str, str],
    failures: Mapping[str, str],
    *,
    run_cfg: Mapping[str, Any] | None = None,
    caches: Mapping[str, str] | None = None,
    fingerprints: Mapping[str, str] | None = None,
    neighbours: Mapping[str, Sequence[str]] | None = None,
    stage_dir: str | os.PathLike[str] | None = None,
    sources: Mapping[str, str] | None = None,
    block_bounds: Mapping[str, Sequence[float] | None] | None = None,
    registry: str | os.PathLike[str] | None = None,
) -> Path:
    """``results/<zone>/`` from the blocks that completed, the failed ones listed.

    Written after a failed run (``--keep-going``): the QA index names each failed
    block and why, and ``INCOMPLETE.txt`` (written before the zone is swapped in) says
    the zone is not complete, so the directory can never be taken for a finished one.
    Only blocks whose products are current (:func:`current_blocks`, when ``caches`` and
    ``fingerprints`` are given) are published; the others are listed with the reason.
    Works when no block completed (a QA index of failures, no ``towers.gpkg``).
    """
    if caches is not None and fingerprints is not None:
        ok, stale = current_blocks(files, caches, fingerprints, neighbours)
    else:
        have = {
            Path(rel).stem
            for rel, src in files.items()
            if rel.startswith("qa/") and rel.endswith(".json") and Path(src).exists()
        }
        ok, stale = have, {}
    failures = {**{b: r for b, r in stale.items() if b not in failures}, **failures}
    ok -= set(failures)
    have = {rel: src for rel, src in files.items() if Path(rel).stem in ok}
    gpkgs = [src for rel, src in have.items() if rel.startswith("towers/")]
    qa = [src for rel, src in have.items() if rel.startswith("qa/") and rel.endswith(".json")]
    return zone_step(
        zone,
        out_dir,
        have,
        tower_gpkgs=gpkgs,
        qa_jsons=qa,
        failures=failures,
        run_cfg=run_cfg,
        stage_dir=stage_dir,
        sources=sources,
        block_bounds=block_bounds,
        registry=registry,
    )
