"""Splitting a block (paper section 3.1, first step): decode it once into its block cache.

:func:`split_block` (one Snakemake job per block) runs every check that can fail a
block, streams the decoded columns and raw point records into a
:class:`towerpipe.io.blockcache.BlockCache` (memory-mapped by the tiles), and decides
where ground comes from: class 2 when the block has enough of it, else PDAL's SMRF. The
points of the noise classes (ASPRS 7 and 18, and the delivery's own in
``preprocess.extra_noise_classes``) and those whose LAS
*withheld* flag is set ("not to be included in processing") are noise from the cache on
(class 7 in its ``classification`` column): left out of the ground, the DTM, the heights and
the model. The merge writes the input's own records, so they keep their class.
This module also owns the header checks (:func:`header_warnings`) and the zone-CRS
comparison of the split.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe import classes
from towerpipe.config import PreprocessConfig
from towerpipe.errors import InputError, TowerpipeError
from towerpipe.io.blockcache import BlockCache, BlockCacheWriter
from towerpipe.io.diskspace import WORK_BYTES_PER_POINT, require_free
from towerpipe.io.las import (
    BLOCK_COLUMNS,
    BlockHeader,
    check_metric_crs,
    color_info,
    crs_name,
    iter_block,
    read_header,
    same_crs,
)
from towerpipe.io.lasformat import check_format, own_dimensions
from towerpipe.preprocess import tiling
from towerpipe.preprocess.attributes import AttributeStats, degenerate, describe
from towerpipe.progress import Progress, peak_rss_mb

log = logging.getLogger(__name__)


def split_block(
    path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    block: str,
    zone: str | None = None,
    crs: str | None = None,
    zone_crs: str | None = None,
    settings: PreprocessConfig,
    record_errors: bool = False,
    source: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Decode a block once into an uncompressed column cache.

    With ``record_errors``, a block that cannot be read (:class:`InputError`: truncated,
    wrong or missing CRS…) gets a cache holding only ``meta.json`` with the error,
    instead of raising: the neighbouring blocks, whose tiles take buffer points from
    this cache, then go on without this block's points (and say so in their QA), while
    the block's own next step raises the recorded error (:meth:`towerpipe.io.blockcache.BlockCache.open`). A bad
    block thus costs only itself.

    Parameters
    ----------
    path
        The block file (``.las``/``.laz``).
    out_dir
        Cache directory to create (:class:`towerpipe.io.blockcache.BlockCache`): ``{column}.npy``
        for each of :data:`towerpipe.io.las.BLOCK_COLUMNS`, ``records.npy`` (the raw point records,
        so that the merge copies them without decoding the LAZ a second time) and
        ``meta.json``. Written to a
        temporary sibling and renamed, so a crash leaves nothing that looks complete.
    block, zone
        Names (for metadata and messages).
    crs
        The zone's `crs:`, for files without a CRS (:func:`towerpipe.io.las.resolve_crs`).
    zone_crs
        The CRS the zone's other blocks have (WKT); a block in another CRS is refused
        (a zone is one CRS: windows, neighbours and the GeoPackage mix blocks).
    settings
        The ``preprocess`` section (its tile size and ground rule).
    source
        The block's input record (:func:`towerpipe.io.inputs.describe`: original relative
        path, size, fingerprint, ``clash``), kept in ``meta.json`` as ``source``. A block
        with a ``clash`` (the same block in a second file) is refused.

    Every check that can fail a block runs here, before any compute: room on the disk for its
    work files (:func:`towerpipe.io.diskspace.require_free`: a :class:`DiskSpaceError`, never
    recorded), readable, not truncated, a CRS in metres (:func:`towerpipe.io.las.check_metric_crs`), a LAS
    version and point format the merge writes (:func:`towerpipe.io.lasformat.check_format`).
    The tiles come from the points (``bounds``, ``tiles``: the occupied tiles); a header
    whose bounds contradict the points is kept as ``header_warnings`` (a QA warning).

    Returns
    -------
    dict
        The metadata written to ``meta.json``.
    """
    src = dict(source or {})
    try:
        if src.get("clash"):
            raise InputError(
                path,
                f"{src['clash']} is the same block in a second file; keep one of the two "
                "(both are left out until then)",
            )
        return _split_block(
            path, out_dir, block=block, zone=zone, crs=crs, zone_crs=zone_crs, settings=settings, source=src
        )
    except InputError as exc:
        if not record_errors:
            raise
        # the block named on both lines: a split batch's log holds the splits of several blocks
        log.error("block %s: %s: %s", block, type(exc).__name__, exc)
        log.error(
            "block %s: recorded in its cache; it fails at its next step, its neighbours go on without its points", block
        )
        meta = {
            "block": block,
            "zone": zone,
            "path": str(path),
            "source": src,
            "error": {"type": type(exc).__name__, "path": exc.path, "cause": exc.cause},
        }
        try:
            meta["header_bounds"] = list(read_header(path).bounds)
        except TowerpipeError:
            pass
        with BlockCache.create(out_dir) as tmp:
            tmp.write_meta(meta)
        return meta


def _split_block(
    path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    block: str,
    zone: str | None,
    crs: str | None,
    zone_crs: str | None,
    settings: PreprocessConfig,
    source: Mapping[str, Any],
) -> dict[str, Any]:
    cfg = settings
    t0 = time.perf_counter()
    it = iter_block(path, crs=crs, zone=zone, records=True)
    header, crs_wkt = next(it)
    check_format(header.version, header.point_format, path)
    check_metric_crs(path, crs_wkt, zone=zone, from_config=bool(crs) and not header.crs_wkt)
    own = own_dimensions(path)  # towerpipe output is reprocessed; a foreign dimension of that name is refused
    if zone_crs and not crs and not same_crs(crs_wkt, zone_crs):
        raise InputError(
            path,
            f"its CRS ({crs_name(crs_wkt)}) differs from the rest of zone {zone!r} "
            f"({crs_name(zone_crs)}); reproject it or put it in a zone of its own",
        )
    n = header.point_count
    # the block's work files (cache, tiles, classified LAZ), before any is written
    require_free(
        Path(out_dir).parent,
        n * WORK_BYTES_PER_POINT,
        what=f"block {block} ({n:,} points)",
        fix="point `workdir` in the config at a larger disk",
    )
    with BlockCache.create(out_dir) as tmp:
        meta = _stream_block(it, tmp, header, n, cfg, block)
        bounds = meta["bounds"]
        grid = tiling.TileGrid(tuple(bounds), cfg.tile_size)
        x, y = (tmp.column(c) for c in ("x", "y"))
        meta.update(
            block=block,
            zone=zone,
            path=str(path),
            source=dict(source),
            points=n,
            tiles=tiling.occupied_tiles(grid, x, y),
            header_bounds=list(header.bounds),
            header_warnings=header_warnings(header, meta.pop("extent")),
            crs_wkt=crs_wkt,
            crs_from="config" if crs else "file",
            las_version=header.version,
            point_format=header.point_format,
            dimensions=header.dimensions,
            towerpipe_dimensions=own,
        )
        del x, y
        ground_source = meta["ground_source"]
        if ground_source != "class2":
            log.warning(
                "%s: only %d class-2 points (%.1f %%); ground will be classified with PDAL %s",
                path,
                meta["ground_points"],
                100 * meta["ground_fraction"],
                ground_source,
            )
        for w in meta["header_warnings"]:
            log.warning("%s: %s", path, w)
        if meta["degenerate_attributes"]:
            log.warning("%s: sensor attributes that carry no information: %s", path, describe(meta["attributes"]))
        meta["timings"]["split"] = time.perf_counter() - t0
        meta["peak_rss_mb"] = peak_rss_mb()
        tmp.write_meta(meta)
    return meta


def header_warnings(header: BlockHeader, extent: Mapping[str, list[float]], tolerance: float = 1.0) -> list[str]:
    """What a block's header says that its points contradict (for the QA; never used for tiling).

    ``extent`` holds the points' ``mins`` and ``maxs`` (x, y, z); a header bound more
    than ``tolerance`` m (plus one scale step) off is reported.
    """
    hmins, hmaxs = header.mins, header.maxs
    pmins, pmaxs = extent["mins"], extent["maxs"]
    off = max(max(abs(a - b) for a, b in zip(hmins, pmins)), max(abs(a - b) for a, b in zip(hmaxs, pmaxs)))
    if off <= tolerance + max(header.scales):
        return []
    fmt = lambda v: "[" + ", ".join(f"{c:.2f}" for c in v) + "]"  # noqa: E731
    return [
        f"header bounds {fmt(hmins)}-{fmt(hmaxs)} contradict the points {fmt(pmins)}-{fmt(pmaxs)} "
        f"(off by up to {off:.1f} m); tiles follow the points"
    ]


def _stream_block(
    it, tmp: BlockCacheWriter, header: BlockHeader, n: int, cfg: PreprocessConfig, block: str
) -> dict[str, Any]:
    """Stream the decoded chunks of a block into the cache columns; what was measured on the way."""
    t0 = time.perf_counter()
    # streamed into .npy files (header first, then each chunk appended): the cache never
    # sits in this process's memory, so the job's RSS stays at a few chunks at any density
    cols = {c: tmp.column_writer(c, n) for c in BLOCK_COLUMNS}
    records = None  # the raw point records, for the merge (no second decode)
    maxima = dict.fromkeys(("red", "green", "blue", "nir"), 0)
    stats = AttributeStats(header.dimensions)
    mins, maxs = np.full(3, np.inf), np.full(3, -np.inf)
    class_counts = np.zeros(256, np.int64)
    noise_classes = np.asarray(sorted({*classes.NOISE, *cfg.extra_noise_classes}), np.uint8)
    n_noise = n_withheld = 0
    progress = Progress(f"split {block}, read", n, "points", logger=log)
    try:
        for chunk in it:
            progress.update(len(chunk["x"]))
            stats.update(chunk)  # the input's own classes and attributes
            class_counts += np.bincount(chunk["classification"], minlength=256)
            # the delivery's noise classes and its withheld points are noise from here on (the
            # cache's class only: the merge writes the input's records, their class unchanged)
            out = np.isin(chunk["classification"], noise_classes) | chunk["withheld"]
            n_noise += int(out.sum())
            n_withheld += int(chunk["withheld"].sum())
            if out.any():
                cls = np.where(out, classes.LOW_NOISE, chunk["classification"]).astype(np.uint8)
                chunk = {**chunk, "classification": cls}
            for c in BLOCK_COLUMNS:
                cols[c].write(chunk[c])
            if records is None:
                records = tmp.records_writer(n, chunk["records"].shape[1])
            records.write(chunk["records"])
            for c in maxima:
                maxima[c] = max(maxima[c], int(chunk[c].max()))
            mins = np.minimum(mins, [chunk["x"].min(), chunk["y"].min(), chunk["z"].min()])
            maxs = np.maximum(maxs, [chunk["x"].max(), chunk["y"].max(), chunk["z"].max()])
    finally:
        for stream in [*cols.values(), *([] if records is None else [records])]:
            stream.close()
    progress.close()
    t_read = time.perf_counter() - t0
    _, _, color_bits = color_info(header.dimensions, maxima)
    attributes = stats.result()
    has_rgb, has_nir = attributes["rgb"]["valid"], attributes["nir"]["valid"]
    n_ground = int(class_counts[classes.GROUND])
    ground_fraction = n_ground / n
    return {
        "bounds": [float(mins[0]), float(mins[1]), float(maxs[0]), float(maxs[1])],
        "extent": {"mins": mins.tolist(), "maxs": maxs.tolist()},
        "has_rgb": has_rgb,
        "has_nir": has_nir,
        "color_bits": color_bits,
        "attributes": attributes,
        "degenerate_attributes": degenerate(attributes),
        "ground_points": n_ground,
        "ground_fraction": ground_fraction,
        "ground_source": "class2" if ground_fraction >= cfg.min_ground_fraction else cfg.ground_filter,
        "class_counts": {str(k): int(v) for k, v in enumerate(class_counts) if v},
        "noise_classes": noise_classes.tolist(),
        "noise_points": n_noise,
        "withheld_points": n_withheld,
        "timings": {"read": t_read},
    }
