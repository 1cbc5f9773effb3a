"""Reading Snakemake's main log: which blocks failed, and why.

The workflow's ``onerror`` handler publishes an INCOMPLETE zone from what
:func:`failures_from_log` finds in the log Snakemake wrote (its ``Error in rule``
blocks and the job logs they name).
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

#: The rules whose jobs each take a batch of blocks (their log is ``logs/<rule>/<batch>.log``).
BATCH_RULES = ("infer_batch", "products_batch")
#: The rule whose jobs each split a batch of blocks (its batches are drawn from the headers).
SPLIT_BATCH_RULE = "split_batch"


def failures_from_log(
    snakemake_log: str | os.PathLike[str] | Sequence[str],
    work: str,
    batches: Mapping[str, Mapping[str, Sequence[str]]] | None = None,
    split_batches: Mapping[str, Mapping[str, Sequence[str]]] | None = None,
) -> dict[str, dict[str, str]]:
    """Failed blocks per zone, with their one-line reason, from Snakemake's main log.

    The reason is the job log's ``towerpipe`` error line (``InputError: <file>: <cause>``)
    or its last line. ``batches`` (zone → batch → blocks, :mod:`towerpipe.preprocess.batches`)
    names the blocks of a failed batch job, and ``split_batches`` those of a failed split
    batch job: each fails, with the batch's reason.
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
        zone, job = rel[0], rel[3].removesuffix(".log")  # a block, or a batch of blocks
        of = batches if rule in BATCH_RULES else split_batches if rule == SPLIT_BATCH_RULE else None
        in_batch = list(((of or {}).get(zone) or {}).get(job) or [])
        reason = f"{rule} failed"
        if p.exists():
            lines = [ln.strip() for ln in p.read_text(errors="replace").splitlines() if ln.strip()]
            err = [ln for ln in lines if re.search(r"\b\w*Error: ", ln)]
            if err or lines:
                reason = f"{rule}: " + re.sub(r"^.*? ERROR towerpipe: ", "", (err or lines)[-1])[:300]
        for b in in_batch or [job]:
            failures.setdefault(zone, {}).setdefault(b, f"{reason} (batch {job})" if in_batch else reason)
    return failures
