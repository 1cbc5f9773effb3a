"""Reading and validating LiDAR blocks (LAS/LAZ) with laspy.

A *block* is one input file. :func:`read_header` is cheap (header only) and is
used when the workflow is planned; :func:`read_block` decodes the points once,
checks them, and returns columns ready for the preprocessing. Which files are a
zone's blocks, and their ids, is :mod:`towerpipe.io.inputs`'s (it reads headers from here).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import laspy
import numpy as np
from pyproj import CRS
from pyproj.exceptions import CRSError

from towerpipe.errors import InputError

#: Columns every block provides after :func:`read_block` (absent ones are zeros).
BLOCK_COLUMNS = (
    "x",
    "y",
    "z",
    "intensity",
    "red",
    "green",
    "blue",
    "nir",
    "classification",
    "return_number",
    "number_of_returns",
)


def laz_backend() -> laspy.LazBackend:
    """The fastest LAZ backend available (lazrs multi-threaded when installed)."""
    for backend in (laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs, laspy.LazBackend.Laszip):
        if backend.is_available():
            return backend
    raise InputError("<laz>", "no LAZ backend: pip install lazrs")


@dataclass
class BlockHeader:
    """What the workflow needs to know about a block before decoding it.

    Attributes
    ----------
    path
        The file.
    bounds
        ``(xmin, ymin, xmax, ymax)`` from the header.
    point_count
        Number of points announced by the header.
    crs_wkt
        The file's CRS as WKT, or ``None``.
    version, point_format
        LAS version (``"1.4"``) and point format id.
    mins, maxs, scales
        ``(x, y, z)`` bounds and scales from the header (only ever compared with the
        points: see :func:`towerpipe.preprocess.split.header_warnings`).
    """

    path: str
    bounds: tuple[float, float, float, float]
    point_count: int
    crs_wkt: str | None
    version: str
    point_format: int
    dimensions: list[str] = field(default_factory=list)
    mins: tuple[float, float, float] = (0.0, 0.0, 0.0)
    maxs: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scales: tuple[float, float, float] = (0.0, 0.0, 0.0)


def _parse_crs(header: laspy.LasHeader) -> str | None:
    try:
        crs = header.parse_crs()
    except (CRSError, ValueError, IndexError, KeyError):
        return None
    return None if crs is None else crs.to_wkt()


def read_header(path: str | os.PathLike[str]) -> BlockHeader:
    """Read a block's header only.

    Raises
    ------
    InputError
        When the file is missing, is not LAS/LAZ, or its header is broken.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        with laspy.open(path) as reader:
            h = reader.header
            bounds = (float(h.mins[0]), float(h.mins[1]), float(h.maxs[0]), float(h.maxs[1]))
            return BlockHeader(
                path=str(path),
                bounds=bounds,
                point_count=int(h.point_count),
                crs_wkt=_parse_crs(h),
                version=str(h.version),
                point_format=int(h.point_format.id),
                dimensions=list(h.point_format.dimension_names),
                mins=tuple(float(v) for v in h.mins),
                maxs=tuple(float(v) for v in h.maxs),
                scales=tuple(float(v) for v in h.scales),
            )
    except laspy.errors.LaspyException as exc:
        raise InputError(path, f"not a readable LAS/LAZ file ({exc})") from exc
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(path, f"cannot read the LAS header ({exc})") from exc


def resolve_crs(
    path: str | os.PathLike[str], file_wkt: str | None, override: str | None, zone: str | None = None
) -> str:
    """The CRS to use for a block, as WKT.

    The file's own CRS when it has one; else the zone's ``crs:`` (for files without a CRS); else
    an :class:`InputError` naming the config key to set. A file whose CRS differs from the zone's
    ``crs:`` in plan is refused: the products of a block would land where its points are not, or
    disagree with its classified copy (which keeps the file's CRS). Only the horizontal part is
    compared, so a file in ``EPSG:2154+5720`` keeps its vertical datum under ``crs: EPSG:2154``.
    """
    key = f"zones.{zone}.crs" if zone else "crs"
    if override:
        try:
            wanted = CRS.from_user_input(override)
        except CRSError as exc:
            raise InputError(path, f"config key `{key}` = {override!r} is not a CRS ({exc})") from exc
        if not file_wkt:
            return wanted.to_wkt()
        if not same_crs(file_wkt, wanted, horizontal=True):
            raise InputError(
                path,
                f"its CRS ({crs_name(file_wkt)}) differs from config key `{key}` ({crs_name(wanted)}), "
                "which is for files without a CRS: remove the key, or rewrite the file's CRS "
                "(e.g. pdal translate in.laz out.laz --writers.las.a_srs=EPSG:…)",
            )
    if file_wkt:
        return file_wkt
    z = zone or "ZONE"
    raise InputError(path, f'no CRS in the file; set it in the config: `zones: {{{z}: {{crs: "EPSG:…"}}}}`')


def _horizontal(crs: CRS) -> CRS:
    """The horizontal part of a CRS (the first of a compound one)."""
    return crs.sub_crs_list[0] if crs.is_compound else crs


def same_crs(a: str | CRS, b: str | CRS, *, horizontal: bool = False) -> bool:
    """Whether two CRSs (WKT or :class:`pyproj.CRS`) are the same, axis order aside (``horizontal``:
    their plan parts)."""
    ca, cb = CRS.from_user_input(a), CRS.from_user_input(b)
    if horizontal:
        ca, cb = _horizontal(ca), _horizontal(cb)
    return bool(ca.equals(cb, ignore_axis_order=True))


def crs_name(crs: str | CRS) -> str:
    """A CRS (WKT or :class:`pyproj.CRS`) as a reader names it: ``EPSG:<code>``, else its name."""
    c = CRS.from_user_input(crs)
    epsg = c.to_epsg()
    return f"EPSG:{epsg}" if epsg else c.name


_METRE_NAMES = ("metre", "meter", "metres", "meters")


def crs_units(wkt: str) -> dict[str, tuple[str, float] | None]:
    """Horizontal and vertical units of a CRS: ``{"horizontal": (name, metres per unit),
    "vertical": (name, metres per unit) or None}``.

    A compound CRS gives both from its parts; a 3-D CRS its third axis; a 2-D CRS has no
    vertical unit (heights are then taken in the horizontal unit).
    """
    crs = CRS.from_wkt(wkt)
    parts = crs.sub_crs_list or [crs]
    horiz = next((c for c in parts if not c.is_vertical), parts[0])
    vert = next((c for c in parts if c.is_vertical), None)

    def unit(axis) -> tuple[str, float]:
        return axis.unit_name, float(axis.unit_conversion_factor)

    h_axes = horiz.axis_info
    out: dict[str, tuple[str, float] | None] = {"horizontal": unit(h_axes[0]) if h_axes else None, "vertical": None}
    if vert is not None and vert.axis_info:
        out["vertical"] = unit(vert.axis_info[0])
    elif len(h_axes) > 2:
        out["vertical"] = unit(h_axes[2])
    return out


def check_metric_crs(
    path: str | os.PathLike[str], wkt: str, *, zone: str | None = None, from_config: bool = False
) -> None:
    """Refuse a block whose CRS is not in metres (horizontally and vertically).

    Every length in towerpipe (40 m windows, 100 m HAG limit, tile size, tower heights,
    the 80-160 m conductor ring) is in metres, and so are the models' inputs: applied
    to feet or degrees they silently give wrong results.

    Raises
    ------
    InputError
        One line naming the unit, the axis and the fix.
    """
    units = crs_units(wkt)
    name = CRS.from_wkt(wkt).name
    where = f"config key `zones.{zone or 'ZONE'}.crs`" if from_config else "the file's CRS"
    for axis in ("horizontal", "vertical"):
        u = units[axis]
        if u is None or (u[0].lower() in _METRE_NAMES and abs(u[1] - 1.0) < 1e-12):
            continue
        raise InputError(
            path,
            f"{where} ({name}) has {axis} unit {u[0]!r}; towerpipe's parameters and models "
            "are in metres: reproject the block to a metre CRS (e.g. pdal translate with "
            "filters.reprojection)",
        )


@dataclass
class Block:
    """Decoded columns of one block plus what was learned while reading it."""

    columns: dict[str, np.ndarray]
    header: BlockHeader
    crs_wkt: str
    has_rgb: bool
    has_nir: bool
    color_bits: int

    def __len__(self) -> int:
        return len(self.columns["x"])


def _chunk_columns(points: laspy.ScaleAwarePointRecord, dims: set[str]) -> dict[str, np.ndarray]:
    n = len(points)
    cols: dict[str, np.ndarray] = {
        "x": np.asarray(points.x, dtype=np.float64),
        "y": np.asarray(points.y, dtype=np.float64),
        "z": np.asarray(points.z, dtype=np.float64),
        "intensity": np.asarray(points.intensity, dtype=np.uint16),
        "classification": np.asarray(points.classification, dtype=np.uint8),
        "return_number": np.asarray(points.return_number, dtype=np.uint8),
        "number_of_returns": np.asarray(points.number_of_returns, dtype=np.uint8),
        # not a cache column: the split leaves these points out of the processing (LAS: "should
        # not be included in processing")
        "withheld": np.asarray(points.withheld, dtype=bool),
    }
    for name in ("red", "green", "blue", "nir"):
        cols[name] = np.asarray(points[name], dtype=np.uint16) if name in dims else np.zeros(n, np.uint16)
    return cols


def iter_block(
    path: str | os.PathLike[str],
    *,
    crs: str | None = None,
    zone: str | None = None,
    chunk_size: int = 2_000_000,
    records: bool = False,
):
    """Check a block and decode it chunk by chunk.

    Parameters
    ----------
    records
        Also yield each chunk's raw point records (key ``"records"``: ``(m, record
        size)`` uint8, the bytes of the file's point records as decoded).

    Yields
    ------
    BlockHeader, str
        First item: the header and the resolved CRS (WKT).
    dict[str, numpy.ndarray]
        Then one dict of :data:`BLOCK_COLUMNS` per chunk, in file order.

    Raises
    ------
    InputError
        Not a LAS file, truncated, zero points, non-finite coordinates, or no
        CRS (and no zone ``crs:``), or a CRS other than the zone's ``crs:``.
    """
    header = read_header(path)
    crs_wkt = resolve_crs(path, header.crs_wkt, crs, zone)
    if header.point_count == 0:
        raise InputError(path, "the file holds zero points")
    yield header, crs_wkt
    dims = set(header.dimensions)
    seen = 0
    try:
        with laspy.open(path, laz_backend=laz_backend()) as reader:
            for points in reader.chunk_iterator(chunk_size):
                if len(points) == 0:
                    break
                cols = _chunk_columns(points, dims)
                if records:
                    raw = points.array
                    cols["records"] = raw.view(np.uint8).reshape(len(raw), raw.dtype.itemsize)
                if not (np.isfinite(cols["x"]).all() and np.isfinite(cols["y"]).all() and np.isfinite(cols["z"]).all()):
                    raise InputError(path, "non-finite coordinates")
                seen += len(points)
                yield cols
    except (laspy.errors.LaspyException, OSError, ValueError, EOFError, RuntimeError) as exc:
        raise InputError(path, f"truncated or corrupt point data after {seen} points ({exc})") from exc
    if seen < header.point_count:
        raise InputError(path, f"truncated: header announces {header.point_count} points, file holds {seen}")


def color_info(dims: set[str] | list[str], maxima: dict[str, int]) -> tuple[bool, bool, int]:
    """``(has_rgb, has_nir, color_bits)`` from per-channel maxima over a block.

    Colour stored as 8-bit values in the 16-bit LAS fields (max <= 255) gives
    ``color_bits == 8``; the features scale it accordingly.
    """
    dims = set(dims)
    has_rgb = "red" in dims and any(maxima.get(c, 0) > 0 for c in ("red", "green", "blue"))
    has_nir = "nir" in dims and maxima.get("nir", 0) > 0
    cmax = max((maxima.get(c, 0) for c in ("red", "green", "blue", "nir")), default=0)
    return has_rgb, has_nir, (8 if has_rgb and cmax <= 255 else 16)


def read_block(path: str | os.PathLike[str], *, crs: str | None = None, zone: str | None = None) -> Block:
    """Decode a whole block and check it (see :func:`iter_block`).

    Parameters
    ----------
    path
        A ``.las``/``.laz`` file.
    crs
        The CRS of a file without one (the zone's ``crs:`` key; :func:`resolve_crs`).
    zone
        Zone name, used in error messages.
    """
    it = iter_block(path, crs=crs, zone=zone)
    header, crs_wkt = next(it)
    chunks = list(it)
    cols = {k: np.concatenate([c[k] for c in chunks]) for k in BLOCK_COLUMNS}
    maxima = {c: int(cols[c].max()) for c in ("red", "green", "blue", "nir")}
    has_rgb, has_nir, bits = color_info(header.dimensions, maxima)
    return Block(cols, header, crs_wkt, has_rgb, has_nir, bits)


def las_header_for(
    template: laspy.LasHeader | None = None,
    *,
    point_format: int = 8,
    crs_wkt: str | None = None,
    scales=(0.01, 0.01, 0.01),
    offsets=(0.0, 0.0, 0.0),
) -> laspy.LasHeader:
    """A LAS 1.4 header with the CRS stored as WKT and the WKT global-encoding bit set.

    PDAL 2.2 warns ("Global encoding WKT flag not set for point format 6 - 10")
    on LAS 1.4 files without that bit.
    """
    header = laspy.LasHeader(point_format=point_format, version="1.4")
    header.scales = np.asarray(scales, dtype=np.float64)
    header.offsets = np.asarray(offsets, dtype=np.float64)
    if crs_wkt:
        header.add_crs(CRS.from_wkt(crs_wkt))
        header.global_encoding.wkt = True
    return header


def header_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A JSON-able summary of a block header (for logs and QA)."""
    h = read_header(path)
    return {
        "path": h.path,
        "bounds": list(h.bounds),
        "point_count": h.point_count,
        "version": h.version,
        "point_format": h.point_format,
        "has_crs": h.crs_wkt is not None,
        "dimensions": h.dimensions,
    }
