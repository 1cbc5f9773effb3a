"""Publishing a zone: ``results/<zone>/`` from its blocks' products, complete or not.

The zone's towers, lines and registry (:func:`zone_towers`), the published directory
(:func:`zone_step`, the ``assemble_zone`` job) and, after a failed run, the same from the
blocks whose products are current (:func:`current_blocks`, :func:`assemble_incomplete_zone`,
called by the workflow's ``onerror`` handler).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from towerpipe import __version__
from towerpipe.io.atomic import assemble_directory, publish_copy, write_text_atomic
from towerpipe.io.blockcache import BlockCache
from towerpipe.io.workdir import remove_gone_blocks
from towerpipe.model.cards import config_hash
from towerpipe.products import layout

if TYPE_CHECKING:  # geopandas is imported by the functions that need it: the DAG does not
    import geopandas as gpd

log = logging.getLogger(__name__)


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

    from towerpipe.products.gpkg import LAYER_CONDUCTORS
    from towerpipe.products.gpkg_read import concat_towers, list_layers, read_metadata
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


def write_zone_gpkg(
    path: str | os.PathLike[str], content: Mapping[str, Any], metadata: Mapping[str, str], *, vanished: bool
) -> None:
    """Write the towers, lines and spans of :func:`zone_towers`'s ``content`` to ``path``
    (:func:`towerpipe.products.gpkg.write_towers_gpkg`), with the vanished towers if ``vanished``."""
    from towerpipe.products.gpkg import write_towers_gpkg

    crs = content["crs"]
    write_towers_gpkg(
        path,
        content["towers"] if len(content["towers"]) else None,
        crs_wkt=crs.to_wkt() if hasattr(crs, "to_wkt") else crs,
        lines=content["lines"],
        spans=content["spans"],
        vanished=content["vanished"] if vanished else None,
        metadata=metadata,
    )


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
    merge_benchmarks: Mapping[str, str] | None = None,
    empty: Mapping[str, str] | None = None,
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
    ``merge_benchmarks`` (block → benchmark TSV of its merge, which runs beside its QA
    page) gives the time and memory of each block's classified LAZ on the QA index.
    ``empty`` (block → file) are the zone's files of zero points: the index lists them, nothing
    else is made of them.
    """
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
            write_zone_gpkg(
                gpkg,
                content,
                {
                    "zone": zone,
                    "towerpipe_version": __version__,
                    **content["metadata"],
                    "assembled_at": run_time.isoformat(),
                    "config_hash": config_hash(run_cfg or {}),
                    "blocks": str(len(tower_gpkgs)),
                    "n_towers": str(len(content["towers"])),
                    "n_lines": str(0 if content["lines"] is None else len(content["lines"])),
                },
                vanished=True,
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
            merge_benchmarks=merge_benchmarks,
            n_towers=None if content is None else len(content["towers"]),
            empty=empty,
            sources=sources,
        )
        if failures:
            (tmp / layout.INCOMPLETE).write_text(
                "This zone is INCOMPLETE: the run failed for these blocks (see qa/index.html):\n"
                + "".join(f"  {b}: {r}\n" for b, r in sorted(failures.items()))
                + "Fix the inputs (or remove them) and rerun the command that made this zone.\n"
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
    if manifest is not None and sources is not None:
        # the intermediates of blocks whose input file is gone (work/ would keep them for ever)
        for block, size in remove_gone_blocks(Path(manifest).parent, sources).items():
            log.info("block %s is no longer in the zone: its intermediates removed (%.1f MB)", block, size / 1e6)
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
    empty: Mapping[str, str] | None = None,
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
        empty=empty,
    )


def set_aside_unplanned(
    plan: str | os.PathLike[str],
    manifest: str | os.PathLike[str],
    results_dir: str | os.PathLike[str],
    aside: str | os.PathLike[str],
    *,
    dry_run: bool = False,
) -> str | None:
    """Set aside what a zone published without its plan, so that the run rebuilds it.

    The plan is missing when a run stopped between a split and the plan, or the plan
    failed. Snakemake then cannot see which products a publication depends on: it keeps
    the manifest of the last assembly (or publishes from it) without rebuilding the zone,
    and leaves an INCOMPLETE ``results_dir`` from such a run as it is. So ``manifest`` is
    removed and an INCOMPLETE ``results_dir`` moved to ``aside`` (replacing one there): the
    run plans the zone and publishes it again, the products still up to date kept. A
    complete ``results_dir`` is never moved.

    Returns
    -------
    str or None
        What was (``dry_run``: would be) done, for the operator; None when the plan exists
        or nothing was published.
    """
    if Path(plan).exists():
        return None
    incomplete = (Path(results_dir) / layout.INCOMPLETE).exists()
    if not (Path(manifest).exists() or incomplete):
        return None
    if dry_run:
        return f"{plan} is missing; a run plans and publishes the zone again"
    Path(manifest).unlink(missing_ok=True)
    if incomplete:
        shutil.rmtree(aside, ignore_errors=True)
        os.replace(results_dir, aside)
    moved = f" (the INCOMPLETE {results_dir}/ is moved to {aside}/)" if incomplete else ""
    return f"{plan} is missing; the zone is planned and published again{moved}"
