"""Reading Snakemake's main log: which blocks failed, and why.

The workflow's ``onerror`` handler publishes an INCOMPLETE zone from what
:func:`failures_from_log` finds in the log Snakemake wrote (its ``Error in rule``
blocks and the job logs they name).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path


def failures_from_log(snakemake_log: str | os.PathLike[str] | Sequence[str], work: str) -> dict[str, dict[str, str]]:
    """Failed blocks per zone, with their one-line reason, from Snakemake's main log.

    The reason is the job log's ``towerpipe`` error line (``InputError: <file>: <cause>``)
    or its last line.
    """
    failures: dict[str, dict[str, str]] = {}
    logs = [snakemake_log] if isinstance(snakemake_log, (str, os.PathLike)) else list(snakemake_log or [])
    text = "\n".join(Path(p).read_text(errors="replace") for p in logs if Path(p).exists())
    work_abs = Path(work).resolve()
    for rule, job_log in re.findall(r"Error in rule (\w+):.*?\n\s+log: (\S+)", text, re.DOTALL):
        p = Path(job_log).resolve()
        try:
            rel = p.relative_to(work_abs).parts  # zone/logs/rule/block(.log | /tile.log)
        except ValueError:
            continue
        if len(rel) < 4 or rel[1] != "logs":
            continue
        zone, block = rel[0], rel[3].removesuffix(".log")
        reason = f"{rule} failed"
        if p.exists():
            lines = [ln.strip() for ln in p.read_text(errors="replace").splitlines() if ln.strip()]
            err = [ln for ln in lines if re.search(r"\b\w*Error: ", ln)]
            if err or lines:
                reason = f"{rule}: " + re.sub(r"^.*? ERROR towerpipe: ", "", (err or lines)[-1])[:300]
        failures.setdefault(zone, {}).setdefault(block, reason)
    return failures
