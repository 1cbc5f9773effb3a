"""The LAS formats towerpipe writes, and the dimensions it adds to a block.

Shared by the split (which refuses a block the merge could not write, before any
compute) and the merge (:mod:`towerpipe.products.merge`, which writes them):

* :data:`SUPPORTED_FORMATS` and :func:`check_format`: the LAS versions and point formats
  read and written;
* :data:`PROB_DIMENSION`, :data:`TOWER_ID_DIMENSION` and :data:`OWN_DIMENSIONS`: the
  extra-bytes dimensions towerpipe appends, and :func:`own_dimensions`, which of them a
  block already carries (it is towerpipe output) or refuses a foreign one of that name;
* :class:`VerbatimExtraBytesVlr`: an Extra Bytes VLR laspy writes byte for byte;
* :class:`KnownStatsWriter`: a writer of points whose header statistics are known.
"""

from __future__ import annotations

import os
from typing import Any

import laspy
import numpy as np
from laspy import PackedPointRecord
from laspy.vlrs.known import ExtraBytesVlr

from towerpipe.errors import InputError

__all__ = [
    "PROB_DIMENSION",
    "TOWER_ID_DIMENSION",
    "OWN_DIMENSIONS",
    "SUPPORTED_FORMATS",
    "check_format",
    "own_dimensions",
    "VerbatimExtraBytesVlr",
    "KnownStatsWriter",
]

#: Name of the extra dimension holding the tower probability.
PROB_DIMENSION = "TowerProbability"
#: Name of the extra dimension holding the tower id of each point (``tower_id`` of the
#: GeoPackage; 0: not a point of a reported tower). Namespaced so that no input dimension
#: (e.g. the synthetic zones' ``TowerId`` labels) is taken for it.
TOWER_ID_DIMENSION = "TowerpipeTowerId"
#: The dimensions towerpipe adds, in record order, with their types and descriptions.
OWN_DIMENSIONS: dict[str, tuple[np.dtype, str]] = {
    PROB_DIMENSION: (np.dtype("float32"), "tower probability (towerpipe)"),
    TOWER_ID_DIMENSION: (np.dtype("uint64"), "tower_id in towers.gpkg"),
}

#: LAS versions and the point formats each defines: all are read and written (COPC files
#: are LAS 1.4 LAZ and read as such; their COPC records are not copied to the output).
SUPPORTED_FORMATS = {
    (1, 1): frozenset(range(2)),
    (1, 2): frozenset(range(4)),
    (1, 3): frozenset(range(6)),
    (1, 4): frozenset(range(11)),
}


def check_format(version: Any, point_format: int, path: str | os.PathLike[str]) -> None:
    """Refuse a LAS version / point format the merge cannot write (checked at split time).

    Parameters
    ----------
    version
        ``"1.4"``, ``(1, 4)`` or a :class:`laspy.header.Version`.
    """
    major, minor = (int(v) for v in (str(version).split(".") if not isinstance(version, tuple) else version))
    if int(point_format) not in SUPPORTED_FORMATS.get((major, minor), ()):
        raise InputError(
            path,
            f"LAS {major}.{minor} point format {point_format} is not a valid LAS point format "
            "(LAS 1.1: 0-1, 1.2: 0-3, 1.3: 0-5, 1.4: 0-10); convert it with pdal translate",
        )


class VerbatimExtraBytesVlr(ExtraBytesVlr):
    """An Extra Bytes VLR that laspy's writer leaves byte for byte as given.

    laspy resets and recomputes the min/max statistics of extra-bytes descriptors when
    writing; the input descriptors must come out unchanged, so this VLR ignores that.
    """

    def partial_reset(self) -> None:  # noqa: D102 - deliberately a no-op
        pass

    def grow(self, points: PackedPointRecord) -> None:  # noqa: D102 - deliberately a no-op
        pass


class KnownStatsWriter(laspy.LasWriter):
    """A :class:`laspy.LasWriter` that counts the points it writes without measuring them.

    laspy's writer grows the header's bounds, counts by return and extra-bytes statistics over
    every chunk it writes (0.2 of the 3.7 s a single-threaded merge of 9.87 M points took). The merge writes a
    block's own points: their statistics are the input header's, set on this writer's ``header``
    before it closes, and the extra-bytes statistics are set before writing.
    """

    def write_points(self, points: PackedPointRecord) -> None:
        """Write ``points`` (in this writer's point format, scales and offsets) and count them."""
        if self.done:
            raise laspy.errors.LaspyException("Cannot write points anymore")
        if points.point_format != self.header.point_format:
            raise laspy.errors.LaspyException("Incompatible point formats")
        self.header.point_count += len(points)
        self.point_writer.write_points(points)


def own_dimensions(
    header: laspy.LasHeader | str | os.PathLike[str], path: str | os.PathLike[str] | None = None
) -> list[str]:
    """The dimensions of :data:`OWN_DIMENSIONS` a block already has (it is towerpipe output).

    Parameters
    ----------
    header
        The block's laspy header, or its path (the header is read).
    path
        The file, for messages (default: ``header`` when it is a path).

    Raises
    ------
    InputError
        A dimension has one of towerpipe's names but another type or a scale/offset:
        somebody else's dimension, which the output would overwrite.
    """
    if not isinstance(header, laspy.LasHeader):
        path = header if path is None else path
        with laspy.open(header) as reader:
            header = reader.header
    names = set(header.point_format.dimension_names)
    found = []
    for name, (dtype, _) in OWN_DIMENSIONS.items():
        if name not in names:
            continue
        dim = header.point_format.dimension_by_name(name)
        scaled = getattr(dim, "scales", None) is not None or getattr(dim, "offsets", None) is not None
        if dim.is_standard or dim.dtype != dtype or scaled:
            raise InputError(
                path or "<block>",
                f"has a dimension {name!r} of type {dim.dtype}"
                f"{' (scaled)' if scaled else ''}, but towerpipe writes {name!r} "
                f"as unscaled {dtype}; rename or remove that dimension (e.g. with "
                "PDAL filters.ferry / writers.las extra_dims) and rerun",
            )
        found.append(name)
    return found
