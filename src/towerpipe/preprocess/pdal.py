"""Running PDAL through its command-line tool with JSON pipelines.

PDAL has no Python wheel on the target machines, so the CLI is the interface:
``pdal pipeline --stdin`` with the pipeline JSON on standard input.
"""

from __future__ import annotations

import functools
import json
import re
import shutil
import subprocess
import time
from typing import Any

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
