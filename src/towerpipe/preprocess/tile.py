"""Preprocessing (paper section 3.1): ground, DTM, height above ground, noise.

Two steps, each one Snakemake job:

1. :func:`split_block` (one per block) decodes the block **once** into an
   uncompressed column cache (``.npy`` per column, memory-mapped by the next
   step) and decides where ground comes from: class 2 when the block has
   enough of it, else PDAL's SMRF.
2. :func:`preprocess_tile` (one per tile, in parallel) gathers the tile's core
   and buffer points from the block's cache and its neighbours', builds a DTM
   from the ground points with PDAL ``writers.gdal``, fills its holes (under
   buildings, water) with :func:`rasterio.fill.fillnodata`, computes heights
   above ground with PDAL ``filters.hag_dem`` (linear in the point count, unlike
   ``filters.hag_nn`` in PDAL 2.2), flags noise, and writes a
   :mod:`towerpipe.io.tiles`.

Nothing is deleted from the block: noise and ground are only excluded from the
model input (``model_input`` flag); the merge step writes every point back.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import laspy
import numpy as np
import rasterio
from rasterio.fill import fillnodata

from towerpipe import classes
from towerpipe.preprocess import tiling
from towerpipe.io.atomic import write_text_atomic
from towerpipe.preprocess.attributes import AttributeStats, degenerate, describe, valid_set
from towerpipe.io.columns import read_meta
from towerpipe.errors import InputError, TowerpipeError
from towerpipe.io.las import (BLOCK_COLUMNS, RECORDS_FILE, BlockHeader, check_metric_crs, color_info, iter_block,
                             read_header)
from towerpipe.products.merge import own_dimensions
from towerpipe.preprocess.pdal import run_pipeline
from towerpipe.progress import Progress
from towerpipe.progress import peak_rss_mb
from towerpipe.io.tiles import Tile, empty_arrays, save_tile

log = logging.getLogger(__name__)

CACHE_META = "meta.json"
NODATA = -9999.0
#: The stages of a tile after gathering its points (each logged as done, with the time left).
TILE_STAGES = ("ground", "dtm", "hag", "noise")


@dataclass
class PreprocessConfig:
    """Parameters of the preprocessing (the ``preprocess:`` section of the config).

    Attributes
    ----------
    tile_size
        Side of a tile in metres.
    buffer
        Buffer around a tile core in metres (at least one window).
    dtm_resolution
        DTM cell size in metres.
    hag_max
        Points higher above ground are noise (paper: 100 m).
    hag_min
        Points lower than this below the DTM are noise (low outliers).
    min_ground_fraction
        Below this share of class-2 points, ground is classified with PDAL.
    ground_filter
        ``"smrf"`` or ``"csf"``.
    outlier
        Run PDAL's statistical outlier filter (slow: superlinear in PDAL 2.2).
    """

    tile_size: float = 500.0
    buffer: float = 40.0
    dtm_resolution: float = 1.0
    hag_max: float = 100.0
    hag_min: float = -2.0
    min_ground_fraction: float = 0.02
    ground_filter: str = "smrf"
    outlier: bool = False
    outlier_mean_k: int = 8
    outlier_multiplier: float = 3.0

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> "PreprocessConfig":
        d = dict(d or {})
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})


# --------------------------------------------------------------------------- split


def split_block(path: str | os.PathLike[str], out_dir: str | os.PathLike[str], *, block: str,
                zone: str | None = None, crs: str | None = None, zone_crs: str | None = None,
                config: PreprocessConfig | None = None, record_errors: bool = False,
                source: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Decode a block once into an uncompressed column cache.

    With ``record_errors``, a block that cannot be read (:class:`InputError`: truncated,
    wrong or missing CRS…) gets a cache holding only ``meta.json`` with the error,
    instead of raising: the neighbouring blocks, whose tiles take buffer points from
    this cache, then go on without this block's points (and say so in their QA), while
    the block's own next step raises the recorded error (:meth:`BlockCache.open`). A bad
    block thus costs only itself.

    Parameters
    ----------
    path
        The block file (``.las``/``.laz``).
    out_dir
        Cache directory to create: ``{column}.npy`` for each of
        :data:`towerpipe.io.las.BLOCK_COLUMNS`, ``records.npy`` (the raw point records,
        so that the merge copies them without decoding the LAZ a second time) and
        ``meta.json``. Written to a
        temporary sibling and renamed, so a crash leaves nothing that looks complete.
    block, zone
        Names (for metadata and messages).
    crs
        The zone's CRS override.
    zone_crs
        The CRS the zone's other blocks have (WKT); a block in another CRS is refused
        (a zone is one CRS: windows, neighbours and the GeoPackage mix blocks).
    source
        The block's input record (:func:`towerpipe.io.inputs.describe`: original relative
        path, size, fingerprint, ``clash``), kept in ``meta.json`` as ``source``. A block
        with a ``clash`` (the same block in a second file) is refused.

    Every check that can fail a block runs here, before any compute: readable, not
    truncated, a CRS in metres (:func:`towerpipe.io.las.check_metric_crs`), a LAS
    version and point format the merge writes (:func:`towerpipe.products.merge.check_format`).
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
            raise InputError(path, f"{src['clash']} is the same block in a second file; keep one of the two "
                                   "(both are left out until then)")
        return _split_block(path, out_dir, block=block, zone=zone, crs=crs, zone_crs=zone_crs, config=config,
                            source=src)
    except InputError as exc:
        if not record_errors:
            raise
        log.error("%s: %s", type(exc).__name__, exc)
        log.error("recorded in %s: block %r fails at its next step; its neighbours go on without its points",
                  out_dir, block)
        meta = {"block": block, "zone": zone, "path": str(path), "source": src,
                "error": {"type": type(exc).__name__, "path": exc.path, "cause": exc.cause}}
        try:
            meta["header_bounds"] = list(read_header(path).bounds)
        except TowerpipeError:
            pass
        with _staged(out_dir) as tmp:
            (tmp / CACHE_META).write_text(json.dumps(meta, indent=1))
        return meta


@contextlib.contextmanager
def _staged(out_dir: str | os.PathLike[str]):
    """A staging directory that replaces ``out_dir`` on success and is removed on any failure."""
    tmp = _staging_dir(out_dir)
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _publish_dir(tmp, out_dir)


def _staging_dir(out_dir: str | os.PathLike[str]) -> Path:
    """An empty ``<out_dir>.part`` sibling to write a cache into (a stale one is removed)."""
    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + ".part")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    return tmp


def _publish_dir(tmp: Path, out_dir: str | os.PathLike[str]) -> None:
    """Replace ``out_dir`` by the finished staging directory ``tmp``."""
    shutil.rmtree(out_dir, ignore_errors=True)
    os.replace(tmp, out_dir)


class _NpyStream:
    """Write one ``.npy`` array chunk by chunk: the header for the final shape, then the data."""

    def __init__(self, path: Path, dtype: str, shape: tuple[int, ...]):
        self.path, self.dtype, self.shape = path, np.dtype(dtype), shape
        self.fh = open(path, "wb")
        np.lib.format.write_array_header_1_0(self.fh, {"descr": np.lib.format.dtype_to_descr(self.dtype),
                                                      "fortran_order": False, "shape": shape})
        self.rows = 0

    def write(self, a: np.ndarray) -> None:
        a = np.ascontiguousarray(a, dtype=self.dtype)
        if a.shape[1:] != self.shape[1:] or self.rows + len(a) > self.shape[0]:
            raise TowerpipeError(f"{self.path}: chunk {a.shape} does not fit the array {self.shape}")
        self.fh.write(a.data)
        self.rows += len(a)

    def close(self) -> None:
        self.fh.close()


def _split_block(path: str | os.PathLike[str], out_dir: str | os.PathLike[str], *, block: str,
                 zone: str | None, crs: str | None, zone_crs: str | None,
                 config: PreprocessConfig | None, source: Mapping[str, Any]) -> dict[str, Any]:
    from towerpipe.products.merge import check_format

    cfg = config or PreprocessConfig()
    t0 = time.perf_counter()
    it = iter_block(path, crs=crs, zone=zone, records=True)
    header, crs_wkt = next(it)
    check_format(header.version, header.point_format, path)
    check_metric_crs(path, crs_wkt, zone=zone, from_config=bool(crs))
    own = own_dimensions(path)  # towerpipe output is reprocessed; a foreign dimension of that name is refused
    if zone_crs and not crs and not _same_crs(crs_wkt, zone_crs):
        raise InputError(path, f"its CRS ({_crs_name(crs_wkt)}) differs from the rest of zone {zone!r} "
                               f"({_crs_name(zone_crs)}); reproject it or put it in a zone of its own")
    n = header.point_count
    with _staged(out_dir) as tmp:
        meta = _stream_block(it, tmp, header, n, cfg, block)
        bounds = meta["bounds"]
        grid = tiling.TileGrid(tuple(bounds), cfg.tile_size)
        x, y = (np.load(tmp / f"{c}.npy", mmap_mode="r") for c in ("x", "y"))
        meta.update(
            block=block, zone=zone, path=str(path), source=dict(source), points=n,
            tiles=tiling.occupied_tiles(grid, x, y), header_bounds=list(header.bounds),
            header_warnings=header_warnings(header, meta.pop("extent")),
            crs_wkt=crs_wkt, crs_from="config" if crs else "file", las_version=header.version,
            point_format=header.point_format, dimensions=header.dimensions, towerpipe_dimensions=own,
        )
        del x, y
        ground_source = meta["ground_source"]
        if ground_source != "class2":
            log.warning("%s: only %d class-2 points (%.1f %%); ground will be classified with PDAL %s",
                        path, meta["ground_points"], 100 * meta["ground_fraction"], ground_source)
        for w in meta["header_warnings"]:
            log.warning("%s: %s", path, w)
        if meta["degenerate_attributes"]:
            log.warning("%s: sensor attributes that carry no information: %s", path, describe(meta["attributes"]))
        meta["timings"]["split"] = time.perf_counter() - t0
        meta["peak_rss_mb"] = peak_rss_mb()
        (tmp / CACHE_META).write_text(json.dumps(meta, indent=1))
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
    return [f"header bounds {fmt(hmins)}-{fmt(hmaxs)} contradict the points {fmt(pmins)}-{fmt(pmaxs)} "
            f"(off by up to {off:.1f} m); tiles follow the points"]


def _stream_block(it, tmp: Path, header: BlockHeader, n: int, cfg: PreprocessConfig, block: str) -> dict[str, Any]:
    """Stream the decoded chunks of a block into the cache columns; what was measured on the way."""
    t0 = time.perf_counter()
    dtypes = {"x": "f8", "y": "f8", "z": "f8", "classification": "u1", "return_number": "u1",
              "number_of_returns": "u1"}
    # streamed into .npy files (header first, then each chunk appended): the cache never
    # sits in this process's memory, so the job's RSS stays at a few chunks at any density
    cols = {c: _NpyStream(tmp / f"{c}.npy", dtypes.get(c, "u2"), (n,)) for c in BLOCK_COLUMNS}
    records: _NpyStream | None = None  # the raw point records, for the merge (no second decode)
    maxima = dict.fromkeys(("red", "green", "blue", "nir"), 0)
    stats = AttributeStats(header.dimensions)
    mins, maxs = np.full(3, np.inf), np.full(3, -np.inf)
    class_counts = np.zeros(256, np.int64)
    progress = Progress(f"split {block}, read", n, "points", logger=log)
    try:
        for chunk in it:
            progress.update(len(chunk["x"]))
            for c in BLOCK_COLUMNS:
                cols[c].write(chunk[c])
            if records is None:
                records = _NpyStream(tmp / RECORDS_FILE, "u1", (n, chunk["records"].shape[1]))
            records.write(chunk["records"])
            for c in maxima:
                maxima[c] = max(maxima[c], int(chunk[c].max()))
            stats.update(chunk)
            mins = np.minimum(mins, [chunk["x"].min(), chunk["y"].min(), chunk["z"].min()])
            maxs = np.maximum(maxs, [chunk["x"].max(), chunk["y"].max(), chunk["z"].max()])
            class_counts += np.bincount(chunk["classification"], minlength=256)
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
        "timings": {"read": t_read},
    }


def _same_crs(a: str, b: str) -> bool:
    from pyproj import CRS

    return CRS.from_wkt(a).equals(CRS.from_wkt(b), ignore_axis_order=True)


def _crs_name(wkt: str) -> str:
    from pyproj import CRS

    c = CRS.from_wkt(wkt)
    epsg = c.to_epsg()
    return f"EPSG:{epsg}" if epsg else c.name


@dataclass
class BlockCache:
    """Memory-mapped columns of a split block."""

    directory: Path
    meta: dict[str, Any]
    _cols: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def open(cls, directory: str | os.PathLike[str], *, allow_failed: bool = False) -> "BlockCache":
        """Open a cache; a cache that records a failed split raises that block's error.

        With ``allow_failed`` it is returned instead (check :attr:`failed`).
        """
        directory = Path(directory)
        try:
            meta = json.loads((directory / CACHE_META).read_text())
        except (OSError, ValueError) as exc:
            raise InputError(directory, f"block cache unreadable ({exc}); rerun the split_block job") from exc
        err = meta.get("error")
        if err and not allow_failed:
            raise InputError(err["path"], err["cause"])
        return cls(directory, meta)

    @property
    def failed(self) -> str | None:
        """The one-line error of a block that could not be split, else ``None``."""
        err = self.meta.get("error")
        return f"{err['type']}: {err['path']}: {err['cause']}" if err else None

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._cols:
            self._cols[name] = np.load(self.directory / f"{name}.npy", mmap_mode="r")
        return self._cols[name]


# --------------------------------------------------------------------------- PDAL steps


def _write_xyz_las(path: Path, x: np.ndarray, y: np.ndarray, z: np.ndarray, origin: tuple[float, float, float],
                   classification: np.ndarray | None = None) -> None:
    """Uncompressed LAS 1.2 point format 0 (xyz at mm precision) for PDAL to read fast."""
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array(origin, dtype=np.float64)
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    if classification is not None:
        las.classification = classification
    las.write(path)


def classify_ground(x: np.ndarray, y: np.ndarray, z: np.ndarray, workdir: Path, *,
                    method: str = "smrf", what: str = "tile") -> np.ndarray:
    """Ground mask computed by PDAL (``filters.elm`` for low noise, then SMRF or CSF)."""
    src, dst = workdir / "ground_in.las", workdir / "ground_out.las"
    origin = (float(np.floor(x.min())), float(np.floor(y.min())), float(np.floor(z.min())))
    _write_xyz_las(src, x, y, z, origin)
    ground_stage: dict[str, Any] = {"type": f"filters.{method}", "ignore": "Classification[7:7]"}
    run_pipeline([
        {"type": "readers.las", "filename": str(src)},
        {"type": "filters.assign", "assignment": "Classification[:]=0"},
        {"type": "filters.elm"},
        ground_stage,
        {"type": "writers.las", "filename": str(dst), "minor_version": 2, "dataformat_id": 0},
    ], what=f"{what}: ground classification ({method})")
    return np.asarray(laspy.read(dst).classification) == classes.GROUND


def build_dtm(gx: np.ndarray, gy: np.ndarray, gz: np.ndarray, box: tiling.Bounds, out_tif: Path,
              workdir: Path, *, resolution: float, crs_wkt: str | None, what: str = "tile") -> dict[str, Any]:
    """DTM over ``box`` from ground points (PDAL ``writers.gdal``), holes filled with rasterio.

    Returns
    -------
    dict
        ``cells``, ``empty_cells`` (before filling), ``filled`` (bool), ``fallback`` (str or None).
    """
    xmin, ymin, xmax, ymax = box
    width = max(1, int(np.ceil((xmax - xmin) / resolution)))
    height = max(1, int(np.ceil((ymax - ymin) / resolution)))
    raw = workdir / "dtm_raw.tif"
    nodata = NODATA
    info: dict[str, Any] = {"cells": width * height, "fallback": None}
    if len(gx) >= 3:
        src = workdir / "ground.las"
        _write_xyz_las(src, gx, gy, gz, (float(np.floor(xmin)), float(np.floor(ymin)), float(np.floor(gz.min()))))
        run_pipeline([
            {"type": "readers.las", "filename": str(src)},
            {"type": "writers.gdal", "filename": str(raw), "resolution": resolution,
             "output_type": "mean", "window_size": 2, "data_type": "float32", "nodata": nodata,
             "bounds": f"([{xmin},{xmin + width * resolution}],[{ymin},{ymin + height * resolution}])"},
        ], what=f"{what}: DTM (writers.gdal)")
        with rasterio.open(raw) as ds:
            dtm = ds.read(1).astype(np.float32)
            transform = ds.transform
    else:
        dtm = np.full((height, width), nodata, np.float32)
        transform = rasterio.transform.from_origin(xmin, ymin + height * resolution, resolution, resolution)
    valid = dtm != nodata
    info["empty_cells"] = int((~valid).sum())
    if not valid.any():
        # No ground at all (e.g. a tile over water or a failed classification): a flat
        # surface at the lowest ground-ish height keeps HAG defined; flagged for QA.
        level = float(np.min(gz)) if len(gz) else 0.0
        dtm[:] = level
        info["fallback"] = "no ground: flat DTM at the lowest height"
    elif not valid.all():
        dtm = fillnodata(dtm, mask=valid.astype(np.uint8), max_search_distance=max(width, height), smoothing_iterations=0)
        still = dtm == nodata
        if still.any():  # isolated pockets fillnodata could not reach
            dtm[still] = float(np.median(dtm[~still]))
    info["filled"] = bool(info["empty_cells"])
    write_raster(out_tif, dtm, transform, crs_wkt)
    return info


def write_raster(path: Path, band: np.ndarray, transform: Any, crs_wkt: str | None) -> None:
    """Write a one-band float32 GeoTIFF atomically."""
    height, width = band.shape
    profile = {"driver": "GTiff", "width": width, "height": height, "count": 1, "dtype": "float32",
               "transform": transform, "nodata": NODATA, "compress": "deflate",
               "tiled": width >= 256 and height >= 256}
    if crs_wkt:
        profile["crs"] = rasterio.crs.CRS.from_wkt(crs_wkt)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part.tif")
    try:
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(band, 1)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def height_above_ground(x: np.ndarray, y: np.ndarray, z: np.ndarray, dtm_tif: Path, workdir: Path, *,
                        what: str = "tile") -> np.ndarray:
    """HAG of every point from the DTM with PDAL ``filters.hag_dem`` (point order kept)."""
    src, dst = workdir / "points.las", workdir / "hag.las"
    origin = (float(np.floor(x.min())), float(np.floor(y.min())), float(np.floor(z.min())))
    _write_xyz_las(src, x, y, z, origin)
    run_pipeline([
        {"type": "readers.las", "filename": str(src)},
        {"type": "filters.hag_dem", "raster": str(dtm_tif), "zero_ground": False},
        {"type": "writers.las", "filename": str(dst), "minor_version": 2, "dataformat_id": 0,
         "extra_dims": "HeightAboveGround=float32"},
    ], what=f"{what}: height above ground (filters.hag_dem)")
    out = laspy.read(dst)
    if len(out.points) != len(x):
        raise InputError(dst, f"PDAL returned {len(out.points)} points for {len(x)}")
    return np.asarray(out["HeightAboveGround"], dtype=np.float32)


def statistical_outliers(x: np.ndarray, y: np.ndarray, z: np.ndarray, workdir: Path, *, mean_k: int,
                         multiplier: float, what: str = "tile") -> np.ndarray:
    """Mask of statistical outliers (PDAL ``filters.outlier``; slow, off by default)."""
    src, dst = workdir / "outlier_in.las", workdir / "outlier_out.las"
    origin = (float(np.floor(x.min())), float(np.floor(y.min())), float(np.floor(z.min())))
    _write_xyz_las(src, x, y, z, origin)
    run_pipeline([
        {"type": "readers.las", "filename": str(src)},
        {"type": "filters.assign", "assignment": "Classification[:]=0"},
        {"type": "filters.outlier", "method": "statistical", "mean_k": mean_k, "multiplier": multiplier},
        {"type": "writers.las", "filename": str(dst), "minor_version": 2, "dataformat_id": 0},
    ], what=f"{what}: outlier filter")
    return np.asarray(laspy.read(dst).classification) == 7


# --------------------------------------------------------------------------- tile


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
        note = (f"buffer points of block {other.get('block')} have no valid {' or '.join(lacks)}: "
                "used for ground and heights only, not as model input")
    elif shift:
        note = (f"buffer points of block {other.get('block')} have {other.get('color_bits')}-bit colour: "
                f"rescaled to {own.get('color_bits')} bits")
    return not lacks, shift, note


def gather_tile(zone: str, block: str, tile: str, caches: Mapping[str, BlockCache],
                cfg: PreprocessConfig) -> Tile:
    """Core points of ``block`` in ``tile`` plus buffer points of every cached block.

    The tile grid comes from the block's points (``bounds`` measured by the split). A
    neighbour with other sensor attributes is handled by :func:`buffer_attributes`; its
    notes are ``meta["buffer_notes"]`` and its geometry-only points
    ``meta["geometry_only_blocks"]``.
    """
    grid = tiling.TileGrid(tuple(caches[block].meta["bounds"]), cfg.tile_size)
    core_box = grid.core_box(tile)
    box = tiling.expand(core_box, cfg.buffer)
    names = sorted(caches)
    own = caches[block].meta
    parts: list[dict[str, np.ndarray]] = []
    notes: list[str] = []
    geometry_only: list[str] = []
    for bid, name in enumerate(names):
        c = caches[name]
        x, y = c["x"], c["y"]
        if name == block:  # the core by grid index (robust to points beyond the header bounds)
            is_core_all = grid.core_mask(x, y, tile)
            sel = np.flatnonzero(is_core_all | tiling.box_mask(x, y, box))
            is_core = is_core_all[sel]
        elif tiling.intersects(box, tuple(c.meta["bounds"])):
            sel = np.flatnonzero(tiling.box_mask(x, y, box))
            is_core = np.zeros(sel.size, bool)
        else:
            continue
        if sel.size == 0:
            continue
        part = {col: np.asarray(c[col][sel]) for col in BLOCK_COLUMNS}
        if name != block:
            ok, shift, note = buffer_attributes(own, c.meta)
            if note:
                notes.append(note)
            if not ok:
                geometry_only.append(name)
            for col in _COLOUR if shift else ():
                v = part[col].astype(np.uint32)
                part[col] = (v << 8 | v if shift > 0 else v >> 8).astype(np.uint16)
        part.update(block_id=np.full(sel.size, bid, np.int32), point_index=sel.astype(np.int64), core=is_core)
        parts.append(part)
    arrays = empty_arrays(0)
    if parts:
        for k in ("x", "y", "z", "intensity", "red", "green", "blue", "nir", "classification",
                  "return_number", "number_of_returns", "block_id", "point_index", "core"):
            arrays[k] = np.concatenate([p[k] for p in parts]).astype(arrays[k].dtype, copy=False)
        n = len(arrays["x"])
        arrays["hag"] = np.zeros(n, np.float32)
        arrays["model_input"] = np.zeros(n, bool)
    meta = {
        "zone": zone, "block": block, "tile": tile, "crs_wkt": own["crs_wkt"],
        "core_bounds": list(core_box), "buffer": cfg.buffer, "tile_size": cfg.tile_size, "blocks": names,
        # the block's own sensor attributes: a neighbour's never fail it (buffer_attributes)
        "has_rgb": own["has_rgb"], "has_nir": own["has_nir"],
        "valid_attributes": sorted(valid_set(own.get("attributes"))),
        "color_bits": own["color_bits"], "ground_source": own["ground_source"],
        "buffer_notes": notes, "geometry_only_blocks": geometry_only,
    }
    return Tile(arrays, meta)


def preprocess_tile(zone: str, block: str, tile: str, cache_dirs: Mapping[str, str | os.PathLike[str]],
                    out_path: str | os.PathLike[str], *, dtm_path: str | os.PathLike[str] | None = None,
                    config: PreprocessConfig | Mapping[str, Any] | None = None,
                    missing: Mapping[str, str | os.PathLike[str]] | None = None) -> dict[str, Any]:
    """Ground, DTM, HAG and noise flags for one tile; writes the tile file.

    Parameters
    ----------
    zone, block, tile
        Names; ``tile`` is a grid id from :func:`towerpipe.preprocess.tiling.tile_ids`.
    cache_dirs
        Block name → cache directory from :func:`split_block`, for ``block``
        and every neighbour that may hold buffer points.
    out_path
        The tile ``.npz`` (:mod:`towerpipe.io.tiles`).
    dtm_path
        Where to keep the filled DTM GeoTIFF (for QA maps); a temporary file if ``None``.
    missing
        Blocks nearby that could not be split (id → cache directory holding the error):
        the tile goes on without their points and says so in its warnings.

    Returns
    -------
    dict
        The tile's metadata (counts, timings, DTM info), also stored in the file.
    """
    cfg = config if isinstance(config, PreprocessConfig) else PreprocessConfig.from_dict(config)
    what = f"{zone}/{block}/{tile}"
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    caches = {b: BlockCache.open(d, allow_failed=b != block) for b, d in cache_dirs.items()}
    for b, d in (missing or {}).items():
        if b not in caches and Path(d, CACHE_META).exists():
            caches[b] = BlockCache.open(d, allow_failed=True)
    warnings = [f"neighbour block {b} could not be read ({c.failed}); no buffer points from it"
                for b, c in sorted(caches.items()) if c.failed]
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
            progress = Progress(f"preprocess {what} ({n:,} points)", len(TILE_STAGES), "stages", logger=log,
                                interval=0.0, show_rate=False)
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
            dtm_info = build_dtm(x[ground], y[ground], z[ground], box, dtm_file, work,
                                 resolution=cfg.dtm_resolution, crs_wkt=t.meta["crs_wkt"], what=what)
            timings["dtm"] = time.perf_counter() - s
            progress.update(detail=f"dtm took {timings['dtm']:.1f} s")
            s = time.perf_counter()
            hag = height_above_ground(x, y, z, dtm_file, work, what=what)
            timings["hag"] = time.perf_counter() - s
            progress.update(detail=f"hag took {timings['hag']:.1f} s")
            s = time.perf_counter()
            noise_hag = (hag > cfg.hag_max) | (hag < cfg.hag_min)
            outlier = np.zeros(n, bool)
            if cfg.outlier:
                cand = ~ground & ~noise_cls & ~noise_hag
                if cand.sum() > cfg.outlier_mean_k:
                    idx = np.flatnonzero(cand)
                    outlier[idx] = statistical_outliers(x[idx], y[idx], z[idx], work, mean_k=cfg.outlier_mean_k,
                                                        multiplier=cfg.outlier_multiplier, what=what)
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
            write_raster(Path(dtm_path), np.full((1, 1), NODATA, np.float32),
                         rasterio.transform.from_origin(t.meta["core_bounds"][0], t.meta["core_bounds"][3],
                                                        cfg.tile_size, cfg.tile_size), t.meta["crs_wkt"])
    timings["total"] = time.perf_counter() - t0
    t.meta.update(counts=counts, timings=timings, dtm=dtm_info, peak_rss_mb=peak_rss_mb(),
                  hag_max=cfg.hag_max, hag_min=cfg.hag_min, warnings=warnings)
    save_tile(out_path, t)
    return t.meta


def summarize_block(cache_dir: str | os.PathLike[str], tile_paths: list[str],
                    out_json: str | os.PathLike[str]) -> dict[str, Any]:
    """Per-block preprocessing summary (counts per stage, ground source, timings) for QA.

    Reads only the metadata of the block cache and of each tile file.
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
        warnings.append("sensor attributes that carry no information: "
                        + "; ".join(f"{a} ({m['attributes'][a]['reason']})" for a in m["degenerate_attributes"]))
    if m["ground_source"] != "class2":
        warnings.append(f"ground had to be classified with PDAL {m['ground_source']} "
                        f"(only {m['ground_points']} class-2 points)")
    # one dict: later stages and other records (e.g. sensor-attribute validity) add keys
    summary = {
        "block": m["block"], "zone": m["zone"], "path": m["path"], "source": m.get("source", {}),
        "points": m["points"], "header_bounds": m.get("header_bounds"),
        "bounds": m["bounds"], "crs_wkt": m["crs_wkt"], "has_rgb": m["has_rgb"], "has_nir": m["has_nir"],
        "attributes": m.get("attributes"), "degenerate_attributes": m.get("degenerate_attributes", []),
        "color_bits": m["color_bits"], "ground_source": m["ground_source"],
        "ground_fraction": m["ground_fraction"], "class_counts": m["class_counts"],
        "counts": totals, "tiles": tiles, "warnings": warnings,
        "timings": {"split": m["timings"]["split"],
                    "tiles": sum(t["timings"].get("total", 0.0) for t in tiles.values())},
    }
    write_text_atomic(out_json, json.dumps(summary, indent=1))
    return summary
