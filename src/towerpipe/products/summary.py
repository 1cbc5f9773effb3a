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

_NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
#: A job of a zone's assembly or publication in Snakemake's log: its rule line and the
#: indented lines under it (its zone from ``wildcards``, or from a ``results/<zone>/``
#: output; its job id).
_ZONE_JOB = re.compile(
    r"^(?:local)?rule (?:assemble_zone|zone_results):\n"
    rf"(?:(?:[ \t]+output: {RESULTS_DIR}/(?P<out>{_NAME})/?[ \t]*\n)"
    r"|(?:[ \t]+jobid: (?P<jobid>\d+)[ \t]*\n)"
    rf"|(?:[ \t]+wildcards: (?:[^\n]*, )?zone=(?P<zone>{_NAME})(?:,[^\n]*)?\n)"
    r"|(?:[ \t]+[^\n]*\n))*",
    re.M,
)


def zones_in_log(snakemake_log: str | os.PathLike[str] | Sequence[str] | None) -> list[str]:
    """Zones a run assembled or (re)published, from Snakemake's main log.

    A zone counts when a job of its assembly (``assemble_zone``: every run that changed a
    block) or of its publication (``zone_results``: ``results/<zone>/`` made anew) finished;
    a job that started and failed does not count (the run's failures are reported apart).
    """
    logs = [snakemake_log] if isinstance(snakemake_log, (str, os.PathLike)) else list(snakemake_log or [])
    text = "\n".join(Path(p).read_text(errors="replace") for p in logs if Path(p).exists())
    finished = set(re.findall(r"^Finished job(?:id:)? (\d+)", text, re.M))
    found = set()
    for m in _ZONE_JOB.finditer(text):
        zone = m["zone"] or m["out"]
        if zone and (m["jobid"] is None or m["jobid"] in finished):
            found.add(zone)
    return sorted(found - {"models"})


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
