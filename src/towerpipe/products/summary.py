"""The end-of-run summary: per zone, towers, failed blocks and where the QA index is.

Printed by the workflow's ``onsuccess`` and ``onerror`` handlers (and by ``towerpipe run``)::

    towerpipe: zone demo: 6 towers in 4 blocks, 0 failed, 1 needs a look; QA index: results/demo/qa/index.html
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

from towerpipe.products import layout

#: Where zones are published (``results/<zone>/``).
RESULTS_DIR = "results"


def zones_in_log(snakemake_log: str | os.PathLike[str] | Sequence[str] | None) -> list[str]:
    """Zones whose results directory a run (re)built, from Snakemake's main log."""
    logs = [snakemake_log] if isinstance(snakemake_log, (str, os.PathLike)) else list(snakemake_log or [])
    text = "\n".join(Path(p).read_text(errors="replace") for p in logs if Path(p).exists())
    found = re.findall(rf"^\s+output: {RESULTS_DIR}/([A-Za-z0-9][A-Za-z0-9_.-]*)/?\s*$", text, re.M)
    return sorted(set(found) - {"models"})


def zone_summary(zone: str, results_dir: str | os.PathLike[str] = RESULTS_DIR) -> str:
    """One line: the zone's towers, blocks, failed blocks and the path of its QA index."""
    out = Path(results_dir) / zone
    index = out / layout.QA_INDEX
    try:
        totals = json.loads((out / layout.QA_INDEX_JSON).read_text(encoding="utf-8"))["totals"]
    except (OSError, ValueError, KeyError):
        return f"zone {zone}: no QA index in {out}/ (the zone was not assembled)"
    look = totals.get("look", 0)
    line = (
        f"zone {zone}: {totals.get('towers', 0)} towers in {totals.get('blocks', 0)} blocks, "
        f"{totals.get('failed', 0)} failed"
    )
    if look:
        line += f", {look} need{'s' if look == 1 else ''} a look"
    return f"{line}; QA index: {index}"


def print_summary(zones: Iterable[str], results_dir: str | os.PathLike[str] = RESULTS_DIR) -> list[str]:
    """Print :func:`zone_summary` of each zone (``towerpipe:`` first); returns the lines."""
    lines = [zone_summary(z, results_dir) for z in zones]
    for line in lines:
        print(f"towerpipe: {line}", flush=True)
    return lines
