"""Running PDAL through its command-line tool with JSON pipelines.

PDAL has no Python wheel on the target machines, so the CLI is the interface:
``pdal pipeline --stdin`` with the pipeline JSON on standard input. A pipeline hands its
result back as a file: a dimension or two as a binary PLY, read by :func:`read_ply_column`.
"""

from __future__ import annotations

import functools
import json
import os
import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.errors import PdalError
from towerpipe.io.diskspace import raise_if_full

MIN_VERSION = (2, 2)
INSTALL_HINT = "install it with `bash scripts/install_pdal.sh` (Debian 12) or `mamba install -c conda-forge pdal`"


@functools.lru_cache(maxsize=1)
def pdal_version() -> str:
    """The PDAL version string (e.g. ``"2.2.0"``).

    Raises
    ------
    PdalError
        When ``pdal`` is not on PATH, ``pdal --version`` fails, or it is older than 2.2.
    """
    exe = shutil.which("pdal")
    if exe is None:
        raise PdalError(f"the `pdal` command is not on PATH; {INSTALL_HINT}")
    try:
        proc = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise PdalError(f"`pdal --version` could not run ({exc}); {INSTALL_HINT}") from exc
    if proc.returncode != 0:
        raise PdalError(f"`pdal --version` exited with {proc.returncode} ({proc.stderr.strip()[:200]}); {INSTALL_HINT}")
    m = re.search(r"pdal (\d+)\.(\d+)(?:\.(\d+))?", proc.stdout)
    if not m:
        raise PdalError(f"cannot parse `pdal --version` output {proc.stdout[:120]!r}")
    if (int(m.group(1)), int(m.group(2))) < MIN_VERSION:
        raise PdalError(f"PDAL {m.group(0)} is too old (need >= 2.2); {INSTALL_HINT}")
    return ".".join(g for g in m.groups() if g is not None)


def pdal_version_tuple() -> tuple[int, ...]:
    """:func:`pdal_version` as integers, e.g. ``(2, 2, 0)``."""
    return tuple(int(p) for p in pdal_version().split("."))


def run_pipeline(stages: list[dict[str, Any]], *, what: str = "pipeline", timeout: float | None = None) -> float:
    """Run a PDAL pipeline given as a list of stage dicts.

    Parameters
    ----------
    stages
        PDAL stages (``{"type": "readers.las", "filename": ...}``, ...).
    what
        Short description used in error messages (e.g. the file being processed).
    timeout
        Seconds before the pipeline is killed.

    Returns
    -------
    float
        Wall time in seconds.

    Raises
    ------
    PdalError
        When PDAL is unusable or the pipeline exits non-zero (stderr tail in the message).
    DiskSpaceError
        When it exits non-zero and the disk a writer writes to is full.
    """
    pdal_version()
    doc = json.dumps({"pipeline": stages})
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            ["pdal", "pipeline", "--stdin"], input=doc, capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired as exc:
        raise PdalError(f"{what}: PDAL pipeline timed out after {timeout} s") from exc
    if proc.returncode != 0:
        tail = " | ".join(proc.stderr.strip().splitlines()[-3:])
        for stage in stages:  # a writer that failed for want of room: said so
            if "filename" in stage and str(stage.get("type", "")).startswith("writers."):
                raise_if_full(
                    Path(stage["filename"]).parent, what=f"{what}: PDAL pipeline failed (exit {proc.returncode})"
                )
        raise PdalError(f"{what}: PDAL pipeline failed (exit {proc.returncode}): {tail}")
    return time.perf_counter() - t0


#: PLY's scalar property types (the standard names and the sized ones, which PDAL's
#: ``writers.ply`` writes), as numpy little-endian dtypes.
_PLY_TYPES = {
    "char": "<i1",
    "int8": "<i1",
    "uchar": "<u1",
    "uint8": "<u1",
    "short": "<i2",
    "int16": "<i2",
    "ushort": "<u2",
    "uint16": "<u2",
    "int": "<i4",
    "int32": "<i4",
    "uint": "<u4",
    "uint32": "<u4",
    "float": "<f4",
    "float32": "<f4",
    "double": "<f8",
    "float64": "<f8",
}

#: A PLY header longer than this is not one PDAL wrote for a pipeline's dimensions.
_PLY_MAX_HEADER = 65536


def read_ply_column(path: str | os.PathLike[str], name: str) -> np.ndarray:
    """One dimension of the points of a binary little-endian PLY that PDAL's ``writers.ply`` wrote.

    A pipeline that hands back a dimension or two (``"dims": "HeightAboveGround=float32"``)
    writes them as a PLY much faster than as a LAS, which also packs x, y and z. No PLY reader
    is among the dependencies, and this is PDAL's plainest layout: a text header, then the
    points' records packed one after the other.

    Parameters
    ----------
    path
        The PLY. It must hold one element, ``vertex``, whose properties are scalars.
    name
        The property, matched without case (PDAL writes a dimension's name in lower case).

    Returns
    -------
    numpy.ndarray
        ``(count,)`` contiguous, of the property's type, in the points' order.

    Raises
    ------
    PdalError
        When the file is not such a PLY, is truncated, or has no property ``name``.
    DiskSpaceError
        When it is truncated and its disk is full (PDAL ran out of room writing it).
    """
    lines: list[str] = []
    with open(path, "rb") as f:
        while True:
            raw = f.readline(_PLY_MAX_HEADER)
            if not raw.endswith(b"\n") or f.tell() > _PLY_MAX_HEADER:
                raise PdalError(f"{path}: not a PLY written by PDAL's writers.ply (no end of its header)")
            line = raw.decode("ascii", "replace").rstrip("\r\n")
            if line == "end_header":
                break
            lines.append(line)
        offset = f.tell()
    if len(lines) < 2 or lines[0] != "ply" or lines[1].split() != ["format", "binary_little_endian", "1.0"]:
        raise PdalError(f"{path}: not a binary little-endian PLY written by PDAL's writers.ply")
    count, fields = None, []
    for line in lines[2:]:
        words = line.split()
        if words[:2] == ["element", "vertex"] and len(words) == 3 and count is None:
            count = int(words[2]) if words[2].isdigit() else -1
            if count < 0:
                raise PdalError(f"{path}: PLY element {line!r} has no count of points")
        elif words[:1] == ["element"]:
            raise PdalError(f"{path}: a PLY element other than one 'vertex' ({line!r})")
        elif words[:1] == ["property"]:
            if count is None or len(words) != 3 or words[1] not in _PLY_TYPES:
                raise PdalError(f"{path}: PLY property {line!r} is not a scalar of a known type")
            if words[2].lower() in (n for n, _ in fields):
                raise PdalError(f"{path}: PLY property {words[2]!r} twice")
            fields.append((words[2].lower(), _PLY_TYPES[words[1]]))
    names = [n for n, _ in fields]
    if count is None or name.lower() not in names:
        raise PdalError(f"{path}: no PLY property {name!r} (has {names}); add it to the writer's 'dims'")
    body = np.fromfile(path, dtype=np.dtype(fields), count=count, offset=offset)
    if len(body) != count:
        # PDAL 2.2 exits 0 when its writer runs out of room: the file is then cut short
        raise_if_full(path, what=f"{len(body)} points where the header says {count}")
        raise PdalError(f"{path}: {len(body)} points where the header says {count} (a truncated file)")
    return np.ascontiguousarray(body[name.lower()])
