"""Writing synthetic blocks: LAS 1.4, point format 8 (or 6), LAZ, WKT CRS, ``TowerId``."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj

#: name of the tower-instance extra dimension
TOWER_ID_DIM = "TowerId"


def write_block(
    path: str | Path,
    pts: dict[str, np.ndarray],
    crs: str | pyproj.CRS,
    bounds: tuple[float, float, float, float] | None = None,
    parallel: bool = False,
    point_format: int = 8,
) -> None:
    """Write one block as LAZ (or LAS by suffix).

    Parameters
    ----------
    path
        Output file (``.laz`` compresses with lazrs).
    pts
        Arrays as returned by :func:`towerpipe.synth.scene.block_points`.
    crs
        CRS (any pyproj input); stored as a WKT VLR with the WKT global-encoding bit.
    bounds
        Block bounds; the offsets are its lower-left corner (else the data minimum).
    parallel
        Use the multi-threaded lazrs backend.
    point_format
        8 (RGB + NIR) or 6 (no colour: ``red`` ... ``nir`` are not written).
    """
    if point_format not in (6, 8):
        raise ValueError(f"point_format must be 6 or 8, got {point_format}")
    header = laspy.LasHeader(version="1.4", point_format=point_format)
    header.add_extra_dim(
        laspy.ExtraBytesParams(name=TOWER_ID_DIM, type=np.uint32, description="tower instance id, 0 = none")
    )
    header.scales = np.array([0.01, 0.01, 0.01])
    x0 = bounds[0] if bounds else float(np.floor(pts["x"].min())) if len(pts["x"]) else 0.0
    y0 = bounds[1] if bounds else float(np.floor(pts["y"].min())) if len(pts["y"]) else 0.0
    z0 = float(np.floor(pts["z"].min() / 100) * 100) if len(pts["z"]) else 0.0
    header.offsets = np.array([x0, y0, z0])
    header.add_crs(pyproj.CRS.from_user_input(crs))
    header.global_encoding.wkt = True
    header.generating_software = "towerpipe.synth"
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(len(pts["x"]), header=header))
    las.x = pts["x"]
    las.y = pts["y"]
    las.z = pts["z"]
    las.classification = pts["classification"]
    las.return_number = pts["return_number"]
    las.number_of_returns = pts["number_of_returns"]
    las.intensity = pts["intensity"]
    if point_format == 8:
        las.red = pts["red"]
        las.green = pts["green"]
        las.blue = pts["blue"]
        las.nir = pts["nir"]
    las.point_source_id = pts["point_source_id"]
    las.scan_angle = np.round(np.asarray(pts["scan_angle"]) / 0.006).astype(np.int16)
    las.gps_time = pts["gps_time"]
    las[TOWER_ID_DIM] = pts["tower_id"].astype(np.uint32)
    path = Path(path)
    if path.suffix.lower() == ".laz":
        backend = laspy.LazBackend.LazrsParallel if parallel else laspy.LazBackend.Lazrs
        las.write(str(path), laz_backend=backend)
    else:
        las.write(str(path))
