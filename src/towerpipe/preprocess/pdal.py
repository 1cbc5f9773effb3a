"""Running PDAL through its command-line tool with JSON pipelines.

PDAL has no Python wheel on the target machines, so the CLI is the interface:
``pdal pipeline --stdin`` with the pipeline JSON on standard input.
"""

from __future__ import annotations

import functools
import json
import os
import re
import shutil
import subprocess
import time
from typing import Any

import numpy as np

from towerpipe.errors import PdalError

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
        raise PdalError(f"{what}: PDAL pipeline failed (exit {proc.returncode}): {tail}")
    return time.perf_counter() - t0


#: The PLY property types ``writers.ply`` writes, as numpy little-endian dtypes.
_PLY_TYPES = {
    "float32": "<f4",
    "float64": "<f8",
    "float": "<f4",
    "double": "<f8",
    "int32": "<i4",
    "uint32": "<u4",
    "int16": "<i2",
    "uint16": "<u2",
    "int8": "<i1",
    "uint8": "<u1",
}


def read_ply_column(path: str | os.PathLike[str], name: str) -> np.ndarray:
    """One dimension of the points of a binary little-endian PLY that PDAL's ``writers.ply`` wrote.

    A pipeline that returns a dimension or two (``"dims": "HeightAboveGround=float32"``) writes
    them as a PLY much faster than as a LAS, which also packs x, y and z. The file must hold one
    element, ``vertex``, whose properties are scalars; ``name`` is matched without case (PDAL
    writes the dimension's name in lower case).

    Raises
    ------
    PdalError
        When the file is not such a PLY or has no property ``name``.
    """
    with open(path, "rb") as f:
        head = f.read(4096)
    end = head.find(b"end_header\n")
    lines = head[:end].decode("ascii", "replace").splitlines() if end >= 0 else []
    if len(lines) < 3 or lines[0] != "ply" or lines[1] != "format binary_little_endian 1.0":
        raise PdalError(f"{path}: not a binary little-endian PLY written by PDAL's writers.ply")
    count, fields = None, []
    for line in lines[2:]:
        words = line.split()
        if words[:2] == ["element", "vertex"] and len(words) == 3 and count is None:
            count = int(words[2])
        elif words[:1] == ["element"]:
            raise PdalError(f"{path}: a PLY element other than one 'vertex' ({line!r})")
        elif words[:1] == ["property"]:
            if count is None or len(words) != 3 or words[1] not in _PLY_TYPES:
                raise PdalError(f"{path}: PLY property {line!r} is not a scalar of a known type")
            fields.append((words[2].lower(), _PLY_TYPES[words[1]]))
    names = [n for n, _ in fields]
    if count is None or name.lower() not in names:
        raise PdalError(f"{path}: no PLY property {name!r} (has {names}); add it to the writer's 'dims'")
    rec = np.dtype(fields)
    body = np.fromfile(path, dtype=rec, count=count, offset=end + len(b"end_header\n"))
    if len(body) != count:
        raise PdalError(f"{path}: {len(body)} points where the header says {count} (a truncated file)")
    return np.ascontiguousarray(body[name.lower()])
