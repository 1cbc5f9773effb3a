"""Preprocessing a tile (paper section 3.1, second step): ground, DTM, heights, noise.

:func:`prepare_tile` (in one Snakemake job per tile, in parallel) gathers the tile's
core and buffer points from the block's cache (:func:`towerpipe.preprocess.split.split_block`)
and its neighbours' (:func:`gather_tile`, :func:`buffer_attributes`), classifies ground
where the block lacks it, builds a DTM and heights above ground with PDAL
(:mod:`towerpipe.preprocess.ground`) and flags noise; :func:`preprocess_tile` also writes
the tile (:mod:`towerpipe.io.tiles`).
:func:`summarize_block` sums a block's tiles for the QA; :func:`tile_noise` reads back
which points of a written tile it called noise.

Nothing is deleted from the block: noise and ground are only excluded from the
model input (``model_input`` flag); the merge step writes every point back.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rasterio

from towerpipe import classes
from towerpipe.config import PreprocessConfig
from towerpipe.io.blockcache import BlockCache
from towerpipe.io.columns import read_meta
from towerpipe.io.las import BLOCK_COLUMNS
from towerpipe.io.tiles import Tile, empty_arrays, save_tile
from towerpipe.preprocess import tiling
from towerpipe.preprocess.attributes import valid_set
from towerpipe.preprocess.ground import (
    NODATA,
    build_dtm,
    classify_ground,
    height_above_ground,
    statistical_outliers,
    write_raster,
)
from towerpipe.progress import Progress, peak_rss_mb

log = logging.getLogger(__name__)

#: The stages of a tile after gathering its points (each logged as done, with the time left).
TILE_STAGES = ("ground", "dtm", "hag", "noise")


def out_of_range(hag: np.ndarray, hag_min: float, hag_max: float) -> np.ndarray:
    """The points too high or too low above the ground to be anything but noise
    (``preprocess.hag_max``, ``preprocess.hag_min``)."""
    return (hag > hag_max) | (hag < hag_min)


def tile_noise(tile: Tile) -> np.ndarray:
    """The points of a written tile that its preprocessing called noise: classified noise
    (:data:`towerpipe.classes.NOISE`) or out of the tile's height range (its ``hag_min`` and
    ``hag_max``, :func:`out_of_range`). The tile needs ``hag`` and ``classification``. The
    statistical outliers are not recorded in a tile and are not among them."""
    out = np.isin(tile.arrays["classification"], classes.NOISE)
    if tile.meta.get("hag_min") is not None and tile.meta.get("hag_max") is not None:
        hag = np.asarray(tile.arrays["hag"], dtype=np.float64)
        out |= out_of_range(hag, float(tile.meta["hag_min"]), float(tile.meta["hag_max"]))
    return out


_COLOUR = ("red", "green", "blue", "nir")


def buffer_attributes(own: Mapping[str, Any], other: Mapping[str, Any]) -> tuple[bool, int, str | None]:
    """How a neighbour's buffer points join a tile of a block with other sensor attributes.

    Returns ``(model_input_ok, colour_shift, note)``: a neighbour without an attribute
    that is valid on the block (RGB, NIR, intensity, returns: :mod:`towerpipe.preprocess.attributes`) gives points for ground, DTM and HAG only (they never reach the
    model, whose features would read zeros); 8-bit colour beside 16-bit colour is
    rescaled (``colour_shift`` bits to the left); ``note`` says what was done.
    """
    lacks = [a for a in ("rgb", "nir") if own.get(f"has_{a}") and not other.get(f"has_{a}")]
    if own.get("attributes") is not None and other.get("attributes") is not None:
        # valid on the block, degenerate on the neighbour (an all-zero NIR, intensity all 0)
        theirs = valid_set(other.get("attributes"))
        lacks += [a for a in sorted(valid_set(own.get("attributes")) - theirs) if a not in lacks]
    shift = 0
    if own.get("has_rgb") and other.get("has_rgb") and own.get("color_bits") != other.get("color_bits"):
        shift = 8 if own.get("color_bits") == 16 else -8
    note = None
    if lacks:
        note = (
            f"buffer points of block {other.get('block')} have no valid {' or '.join(lacks)}: "
            "used for ground and heights only, not as model input"
        )
    elif shift:
        note = (
            f"buffer points of block {other.get('block')} have {other.get('color_bits')}-bit colour: "
            f"rescaled to {own.get('color_bits')} bits"
        )
    return not lacks, shift, note


#: Points of a cache read at a time while gathering a tile. A block's columns are never mapped
#: whole: a job holds its tile's points, not its block's (a km² at 20 pts/m²: 570 MB less).
GATHER_CHUNK = 2_000_000


def _tile_selection(
    cache: BlockCache, own: bool, grid: tiling.TileGrid, tile: str, box: tiling.Bounds, chunk: int
) -> tuple[np.ndarray, np.ndarray]:
    """Ascending indices of a cache's points in the tile with its buffer, and which are core.

    Core: the block's own points by grid index (robust to points beyond the header bounds).
    Read ``chunk`` points at a time (:class:`~towerpipe.io.blockcache.ColumnReader`).
    """
    xs, ys = cache.reader("x"), cache.reader("y")
    sels, cores = [], []
    for a in range(0, len(xs), chunk):
        x, y = xs[a : a + chunk], ys[a : a + chunk]
        inside = tiling.box_mask(x, y, box)
        if own:
            is_core = grid.core_mask(x, y, tile)
            sel = np.flatnonzero(is_core | inside)
            cores.append(is_core[sel])
        else:
            sel = np.flatnonzero(inside)
            cores.append(np.zeros(sel.size, bool))
        sels.append(sel + a)
    if not sels:
        return np.zeros(0, np.int64), np.zeros(0, bool)
    return np.concatenate(sels).astype(np.int64, copy=False), np.concatenate(cores)


def gather_tile(
    zone: str,
    block: str,
    tile: str,
    caches: Mapping[str, BlockCache],
    cfg: PreprocessConfig,
    *,
    chunk: int = GATHER_CHUNK,
) -> Tile:
    """Core points of ``block`` in ``tile`` plus buffer points of every cached block.

    The tile grid comes from the block's points (``bounds`` measured by the split). A
    neighbour with other sensor attributes is handled by :func:`buffer_attributes`; its
    notes are ``meta["buffer_notes"]`` and its geometry-only points
    ``meta["geometry_only_blocks"]``. The caches are read ``chunk`` points at a time.
    """
    grid = tiling.TileGrid(tuple(caches[block].meta["bounds"]), cfg.tile_size)
    core_box = grid.core_box(tile)
    box = tiling.expand(core_box, cfg.buffer)
    names = sorted(caches)
    own = caches[block].meta
    picked: list[tuple[int, str, np.ndarray, np.ndarray]] = []
    notes: list[str] = []
    geometry_only: list[str] = []
    for bid, name in enumerate(names):
        c = caches[name]
        if name != block and not tiling.intersects(box, tuple(c.meta["bounds"])):
            continue
        sel, is_core = _tile_selection(c, name == block, grid, tile, box, chunk)
        if sel.size:
            picked.append((bid, name, sel, is_core))
    # each column is filled in place, block after block: the tile is never held twice
    arrays = empty_arrays(0)
    if picked:
        n = sum(sel.size for _, _, sel, _ in picked)
        arrays = {k: np.empty(n, dtype=arrays[k].dtype) for k in arrays}
        arrays["hag"][:] = 0
        arrays["model_input"][:] = False
        at = 0
        for bid, name, sel, is_core in picked:
            part = slice(at, at + sel.size)
            at += sel.size
            c = caches[name]
            for col in BLOCK_COLUMNS:
                rows = c.reader(col)
                for lo in range(0, sel.size, chunk):
                    arrays[col][part][lo : lo + chunk] = rows[sel[lo : lo + chunk]]
            arrays["block_id"][part] = bid
            arrays["point_index"][part] = sel
            arrays["core"][part] = is_core
            if name == block:
                continue
            ok, shift, note = buffer_attributes(own, c.meta)
            if note:
                notes.append(note)
            if not ok:
                geometry_only.append(name)
            for col in _COLOUR if shift else ():
                v = arrays[col][part].astype(np.uint32)
                arrays[col][part] = (v << 8 | v if shift > 0 else v >> 8).astype(np.uint16)
    meta = {
        "zone": zone,
        "block": block,
        "tile": tile,
        "crs_wkt": own["crs_wkt"],
        "core_bounds": list(core_box),
        "buffer": cfg.buffer,
        "tile_size": cfg.tile_size,
        "blocks": names,
        # the block's own sensor attributes: a neighbour's never fail it (buffer_attributes)
        "has_rgb": own["has_rgb"],
        "has_nir": own["has_nir"],
        "valid_attributes": sorted(valid_set(own.get("attributes"))),
        "color_bits": own["color_bits"],
        "ground_source": own["ground_source"],
        "buffer_notes": notes,
        "geometry_only_blocks": geometry_only,
    }
    return Tile(arrays, meta)


def preprocess_tile(
    zone: str,
    block: str,
    tile: str,
    cache_dirs: Mapping[str, str | os.PathLike[str]],
    out_path: str | os.PathLike[str],
    *,
    dtm_path: str | os.PathLike[str] | None = None,
    settings: PreprocessConfig,
    missing: Mapping[str, str | os.PathLike[str]] | None = None,
) -> dict[str, Any]:
    """Ground, DTM, HAG and noise flags for one tile (:func:`prepare_tile`); writes the tile file
    ``out_path`` (:mod:`towerpipe.io.tiles`) and returns its metadata."""
    t = prepare_tile(zone, block, tile, cache_dirs, dtm_path=dtm_path, settings=settings, missing=missing)
    save_tile(out_path, t)
    return t.meta


def prepare_tile(
    zone: str,
    block: str,
    tile: str,
    cache_dirs: Mapping[str, str | os.PathLike[str]],
    *,
    dtm_path: str | os.PathLike[str] | None = None,
    settings: PreprocessConfig,
    missing: Mapping[str, str | os.PathLike[str]] | None = None,
) -> Tile:
    """Ground, DTM, HAG and noise flags for one tile, in memory.

    Parameters
    ----------
    zone, block, tile
        Names; ``tile`` is a grid id from :func:`towerpipe.preprocess.tiling.tile_ids`.
    cache_dirs
        Block name → cache directory from :func:`towerpipe.preprocess.split.split_block`, for ``block``
        and every neighbour that may hold buffer points.
    dtm_path
        Where to keep the filled DTM GeoTIFF (for QA maps); a temporary file if ``None``.
    settings
        The ``preprocess`` section.
    missing
        Blocks nearby that could not be split (id → cache directory holding the error):
        the tile goes on without their points and says so in its warnings.

    Returns
    -------
    Tile
        Its arrays (``hag`` and ``model_input`` added) and metadata (counts, timings, DTM info).
    """
    cfg = settings
    what = f"{zone}/{block}/{tile}"
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    caches = {b: BlockCache.open(d, allow_failed=b != block) for b, d in cache_dirs.items()}
    for b, d in (missing or {}).items():
        if b not in caches and BlockCache(d).exists():
            caches[b] = BlockCache.open(d, allow_failed=True)
    warnings = [
        f"neighbour block {b} could not be read ({c.failed}); no buffer points from it"
        for b, c in sorted(caches.items())
        if c.failed
    ]
    caches = {b: c for b, c in caches.items() if not c.failed}
    t = gather_tile(zone, block, tile, caches, cfg)
    warnings += t.meta["buffer_notes"]
    for w in warnings:
        log.warning("%s: %s", block, w)
    timings["gather"] = time.perf_counter() - t0
    n = len(t)
    counts: dict[str, int] = {"points": n, "core": int(t["core"].sum()) if n else 0}
    dtm_info: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="towerpipe-") as tmpd:
        work = Path(tmpd)
        if n:
            progress = Progress(
                f"preprocess {what} ({n:,} points)",
                len(TILE_STAGES),
                "stages",
                logger=log,
                interval=0.0,
                show_rate=False,
            )
            x, y, z, cls = t["x"], t["y"], t["z"], t["classification"]
            noise_cls = np.isin(cls, classes.NOISE)
            s = time.perf_counter()
            if t.meta["ground_source"] == "class2":
                ground = cls == classes.GROUND
            else:
                ground = classify_ground(x, y, z, work, method=t.meta["ground_source"], what=what) & ~noise_cls
            timings["ground"] = time.perf_counter() - s
            progress.update(detail=f"ground took {timings['ground']:.1f} s")
            s = time.perf_counter()
            box = tiling.expand(tuple(t.meta["core_bounds"]), cfg.buffer)
            dtm_file = Path(dtm_path) if dtm_path else work / "dtm.tif"
            dtm_info = build_dtm(
                x[ground],
                y[ground],
                z[ground],
                box,
                dtm_file,
                work,
                resolution=cfg.dtm_resolution,
                crs_wkt=t.meta["crs_wkt"],
                what=what,
            )
            timings["dtm"] = time.perf_counter() - s
            progress.update(detail=f"dtm took {timings['dtm']:.1f} s")
            s = time.perf_counter()
            hag = height_above_ground(x, y, z, dtm_file, work, what=what)
            timings["hag"] = time.perf_counter() - s
            progress.update(detail=f"hag took {timings['hag']:.1f} s")
            s = time.perf_counter()
            noise_hag = out_of_range(hag, cfg.hag_min, cfg.hag_max)
            outlier = np.zeros(n, bool)
            if cfg.outlier:
                cand = ~ground & ~noise_cls & ~noise_hag
                if cand.sum() > cfg.outlier_mean_k:
                    idx = np.flatnonzero(cand)
                    outlier[idx] = statistical_outliers(
                        x[idx],
                        y[idx],
                        z[idx],
                        work,
                        mean_k=cfg.outlier_mean_k,
                        multiplier=cfg.outlier_multiplier,
                        what=what,
                    )
            model_input = ~ground & ~noise_cls & ~noise_hag & ~outlier
            if t.meta["geometry_only_blocks"]:
                geometry_only = [t.meta["blocks"].index(b) for b in t.meta["geometry_only_blocks"]]
                model_input &= ~np.isin(t["block_id"], geometry_only)
            timings["noise"] = time.perf_counter() - s
            progress.update(detail=f"noise took {timings['noise']:.1f} s")
            progress.close()
            t.arrays["hag"] = hag
            t.arrays["model_input"] = model_input
            core = t["core"]
            counts.update(
                ground_core=int((ground & core).sum()),
                noise_class_core=int((noise_cls & core).sum()),
                noise_hag_core=int((noise_hag & ~noise_cls & core).sum()),
                outlier_core=int((outlier & core).sum()),
                model_input_core=int((model_input & core).sum()),
                model_input=int(model_input.sum()),
            )
        elif dtm_path:  # no points in this tile: an all-nodata DTM keeps the products uniform
            write_raster(
                Path(dtm_path),
                np.full((1, 1), NODATA, np.float32),
                rasterio.transform.from_origin(
                    t.meta["core_bounds"][0], t.meta["core_bounds"][3], cfg.tile_size, cfg.tile_size
                ),
                t.meta["crs_wkt"],
            )
    timings["total"] = time.perf_counter() - t0
    t.meta.update(
        counts=counts,
        timings=timings,
        dtm=dtm_info,
        peak_rss_mb=peak_rss_mb(),
        hag_max=cfg.hag_max,
        hag_min=cfg.hag_min,
        warnings=warnings,
    )
    return t


def summarize_block(cache_dir: str | os.PathLike[str], tile_paths: Sequence[str]) -> dict[str, Any]:
    """Per-block preprocessing summary (counts per stage, ground source, timings) for QA.

    Reads only the metadata of the block cache and of each tile file (milliseconds: the
    QA job computes it, no job of its own). A block whose split failed raises its error.
    """
    cache = BlockCache.open(cache_dir)
    totals: dict[str, int] = {}
    tiles: dict[str, Any] = {}
    warnings: list[str] = []
    for p in tile_paths:
        meta = read_meta(p)
        tiles[meta["tile"]] = {k: meta.get(k) for k in ("counts", "timings", "dtm", "peak_rss_mb")}
        for k, v in meta.get("counts", {}).items():
            if k.endswith("_core") or k == "core":
                totals[k] = totals.get(k, 0) + int(v)
        fallback = (meta.get("dtm") or {}).get("fallback")
        if fallback:
            warnings.append(f"tile {meta['tile']}: {fallback}")
        warnings += [f"tile {meta['tile']}: {w}" for w in meta.get("warnings", [])]
    m = cache.meta
    warnings = [f"header: {w}" for w in m.get("header_warnings", [])] + warnings
    if totals.get("core", m["points"]) != m["points"]:
        warnings.append(f"tile cores hold {totals.get('core')} points, the block {m['points']}")
    if m.get("degenerate_attributes"):
        warnings.append(
            "sensor attributes that carry no information: "
            + "; ".join(f"{a} ({m['attributes'][a]['reason']})" for a in m["degenerate_attributes"])
        )
    if m["ground_source"] != "class2":
        warnings.append(
            f"ground had to be classified with PDAL {m['ground_source']} (only {m['ground_points']} class-2 points)"
        )
    # one dict: later stages and other records (e.g. sensor-attribute validity) add keys
    summary = {
        "block": m["block"],
        "zone": m["zone"],
        "path": m["path"],
        "source": m.get("source", {}),
        "points": m["points"],
        "header_bounds": m.get("header_bounds"),
        "bounds": m["bounds"],
        "crs_wkt": m["crs_wkt"],
        "has_rgb": m["has_rgb"],
        "has_nir": m["has_nir"],
        "attributes": m.get("attributes"),
        "degenerate_attributes": m.get("degenerate_attributes", []),
        "color_bits": m["color_bits"],
        "ground_source": m["ground_source"],
        "ground_fraction": m["ground_fraction"],
        "class_counts": m["class_counts"],
        # the points the split made noise (the delivery's noise classes, the withheld flag)
        "noise_classes": m.get("noise_classes"),
        "noise_points": m.get("noise_points"),
        "withheld_points": m.get("withheld_points"),
        "counts": totals,
        "tiles": tiles,
        "warnings": warnings,
        "timings": {
            "split": m["timings"]["split"],
            "tiles": sum(t["timings"].get("total", 0.0) for t in tiles.values()),
        },
    }
    return summary
