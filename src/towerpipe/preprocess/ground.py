"""Ground and heights (paper section 3.1): PDAL's ground filters, the DTM and heights above ground.

Each function hands its points to PDAL as an uncompressed LAS file in a work directory, and
PDAL hands back only the dimension asked for, as a binary PLY (:func:`_ply_writer`):
:func:`classify_ground` (``filters.elm`` then SMRF or CSF), :func:`build_dtm`
(``writers.gdal``, holes filled with :func:`rasterio.fill.fillnodata`),
:func:`height_above_ground` (``filters.hag_dem``, linear in the point count, unlike
``filters.hag_nn`` in PDAL 2.2) and :func:`statistical_outliers`. This module also owns
the DTM GeoTIFFs (:func:`write_raster`, :data:`NODATA`) and their per-block mosaic
(:func:`mosaic_dtm`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import laspy
import numpy as np
import rasterio
from rasterio.fill import fillnodata

from towerpipe import classes
from towerpipe.errors import InputError, PdalError
from towerpipe.preprocess import tiling
from towerpipe.preprocess.pdal import pdal_version, pdal_version_tuple, read_ply_column, run_pipeline

#: The DTM's nodata value.
NODATA = -9999.0

#: The last PDAL version whose ``filters.csf`` fails on every input (PDAL issue 3248).
CSF_BROKEN_UP_TO = (2, 2, 0)

#: The coordinate scale (m) of the LAS files handed to PDAL.
_XYZ_SCALE = 0.001

#: The dimension ``filters.hag_dem`` adds.
HAG_DIM = "HeightAboveGround"


def _write_xyz_las(
    path: Path, x: np.ndarray, y: np.ndarray, z: np.ndarray, origin: tuple[float, float, float] | None = None
) -> None:
    """Uncompressed LAS 1.2 point format 0 (xyz at mm precision) for PDAL to read fast.

    ``origin`` is the file's offsets; by default the floor of each coordinate's minimum. The
    records are filled as laspy's scaled setters fill them (the same bytes), without their
    per-dimension bookkeeping: 0.13 s for 2.85 M points, not 0.22 s.
    """
    if origin is None:
        origin = (float(np.floor(x.min())), float(np.floor(y.min())), float(np.floor(z.min())))
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.full(3, _XYZ_SCALE)
    header.offsets = np.array(origin, dtype=np.float64)
    records = np.zeros(len(x), dtype=header.point_format.dtype())
    for dim, v, off in (("X", x, origin[0]), ("Y", y, origin[1]), ("Z", z, origin[2])):
        scaled = np.round((np.asarray(v, dtype=np.float64) - off) / _XYZ_SCALE)
        if len(scaled) and max(-scaled.min(), scaled.max()) > np.iinfo(np.int32).max:
            raise InputError(path, f"{dim} spans more than a LAS file holds at {_XYZ_SCALE} m from {off}")
        records[dim] = scaled
    laspy.LasData(header, points=laspy.PackedPointRecord(records, header.point_format)).write(path)


def _ply_writer(path: Path, dims: str) -> dict[str, Any]:
    """The stage of PDAL's ``writers.ply`` that writes the dimensions ``dims`` alone.

    Read back with :func:`towerpipe.preprocess.pdal.read_ply_column`. PDAL's LAS writer, which
    also packs x, y and z, took 0.5 of a height pipeline's 1.3 s on a tile of 2.8 M points, this
    one 0.1 s.

    Parameters
    ----------
    path
        The PLY to write.
    dims
        ``writers.ply``'s ``dims`` option, e.g. ``"HeightAboveGround=float32"``.
    """
    return {"type": "writers.ply", "filename": str(path), "storage_mode": "little endian", "dims": dims}


def classify_ground(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, workdir: Path, *, method: str = "smrf", what: str = "tile"
) -> np.ndarray:
    """Ground mask computed by PDAL (``filters.elm`` for low noise, then SMRF or CSF).

    Raises
    ------
    PdalError
        With ``method="csf"`` on PDAL 2.2.0, whose ``filters.csf`` fails on every input (PDAL
        issue 3248: ``std::bad_alloc`` or "Point index must increment"), naming the setting to
        change; or when the pipeline fails.
    """
    if method == "csf" and pdal_version_tuple() <= CSF_BROKEN_UP_TO:
        raise PdalError(
            f"{what}: ground classification (csf): the filters.csf of PDAL {pdal_version()} fails on "
            "every input (PDAL issue 3248); set preprocess.ground_filter: smrf, or install a newer PDAL"
        )
    src, dst = workdir / "ground_in.las", workdir / "ground_out.ply"
    _write_xyz_las(src, x, y, z)
    ground_stage: dict[str, Any] = {"type": f"filters.{method}", "ignore": "Classification[7:7]"}
    run_pipeline(
        [
            {"type": "readers.las", "filename": str(src)},
            {"type": "filters.assign", "assignment": "Classification[:]=0"},
            {"type": "filters.elm"},
            ground_stage,
            _ply_writer(dst, "Classification=uint8"),
        ],
        what=f"{what}: ground classification ({method})",
    )
    return read_ply_column(dst, "Classification") == classes.GROUND


def build_dtm(
    gx: np.ndarray,
    gy: np.ndarray,
    gz: np.ndarray,
    box: tiling.Bounds,
    out_tif: Path,
    workdir: Path,
    *,
    resolution: float,
    crs_wkt: str | None,
    what: str = "tile",
) -> dict[str, Any]:
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
        run_pipeline(
            [
                {"type": "readers.las", "filename": str(src)},
                {
                    "type": "writers.gdal",
                    "filename": str(raw),
                    "resolution": resolution,
                    "output_type": "mean",
                    "window_size": 2,
                    "data_type": "float32",
                    "nodata": nodata,
                    "bounds": f"([{xmin},{xmin + width * resolution}],[{ymin},{ymin + height * resolution}])",
                },
            ],
            what=f"{what}: DTM (writers.gdal)",
        )
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
        dtm = fillnodata(
            dtm, mask=valid.astype(np.uint8), max_search_distance=max(width, height), smoothing_iterations=0
        )
        still = dtm == nodata
        if still.any():  # isolated pockets fillnodata could not reach
            dtm[still] = float(np.median(dtm[~still]))
    info["filled"] = bool(info["empty_cells"])
    write_raster(out_tif, dtm, transform, crs_wkt)
    return info


def write_raster(path: Path, band: np.ndarray, transform: Any, crs_wkt: str | None) -> None:
    """Write a one-band float32 GeoTIFF atomically."""
    height, width = band.shape
    profile = {
        "driver": "GTiff",
        "width": width,
        "height": height,
        "count": 1,
        "dtype": "float32",
        "transform": transform,
        "nodata": NODATA,
        "compress": "deflate",
        "tiled": width >= 256 and height >= 256,
    }
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


def height_above_ground(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, dtm_tif: Path, workdir: Path, *, what: str = "tile"
) -> np.ndarray:
    """HAG of every point from the DTM with PDAL ``filters.hag_dem`` (point order kept; PDAL
    writes the heights alone, :func:`_ply_writer`)."""
    src, dst = workdir / "points.las", workdir / "hag.ply"
    _write_xyz_las(src, x, y, z)
    run_pipeline(
        [
            {"type": "readers.las", "filename": str(src)},
            {"type": "filters.hag_dem", "raster": str(dtm_tif), "zero_ground": False},
            _ply_writer(dst, f"{HAG_DIM}=float32"),
        ],
        what=f"{what}: height above ground (filters.hag_dem)",
    )
    hag = read_ply_column(dst, HAG_DIM)
    if len(hag) != len(x):
        raise InputError(dst, f"PDAL returned {len(hag)} points for {len(x)}")
    return hag


def statistical_outliers(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, workdir: Path, *, mean_k: int, multiplier: float, what: str = "tile"
) -> np.ndarray:
    """Mask of statistical outliers (PDAL ``filters.outlier``; slow, off by default)."""
    src, dst = workdir / "outlier_in.las", workdir / "outlier_out.ply"
    _write_xyz_las(src, x, y, z)
    run_pipeline(
        [
            {"type": "readers.las", "filename": str(src)},
            {"type": "filters.assign", "assignment": "Classification[:]=0"},
            {"type": "filters.outlier", "method": "statistical", "mean_k": mean_k, "multiplier": multiplier},
            _ply_writer(dst, "Classification=uint8"),
        ],
        what=f"{what}: outlier filter",
    )
    return read_ply_column(dst, "Classification") == classes.LOW_NOISE


def mosaic_dtm(dtm_paths: Sequence[str | os.PathLike[str]], out: Path) -> Path | None:
    """Mosaic of a block's tile DTMs (for the QA hillshade) written to ``out``.

    Tiles without points (a 1x1 all-nodata DTM) are left out; ``None`` when no tile has one.
    """
    from rasterio.merge import merge

    srcs = []
    try:
        for p in dtm_paths:
            ds = rasterio.open(p)
            if ds.width > 1 or ds.height > 1:
                srcs.append(ds)
            else:
                ds.close()
        if not srcs:
            return None
        mosaic, transform = merge(srcs)
        profile = srcs[0].profile | {
            "width": mosaic.shape[2],
            "height": mosaic.shape[1],
            "transform": transform,
            "tiled": False,
        }
        profile.pop("blockxsize", None)
        profile.pop("blockysize", None)
        with rasterio.open(out, "w", **profile) as dst:
            dst.write(mosaic)
        return out
    finally:
        for ds in srcs:
            ds.close()
