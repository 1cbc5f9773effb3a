"""The zone's QA index: every block, totals, a map, the blocks that need a look, links to the products."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from markupsafe import Markup

from towerpipe.io.atomic import write_text_atomic
from towerpipe.io.inputs import EMPTY_REASON
from towerpipe.products import layout
from towerpipe.products.qa.delivery_classes import zone_user_classes
from towerpipe.products.qa.metrics import jsonable, read_benchmark, tower_flag_reason
from towerpipe.products.qa.pages import render
from towerpipe.products.qa.plots import zone_map
from towerpipe.products.registry_file import reviewed_towers

log = logging.getLogger(__name__)

#: The GeoPackage layer of the lines between towers, when the zone's GeoPackage has one.
LINES_LAYER = "lines"


def _gpkg_lines(gpkg: str | os.PathLike[str] | None) -> list[np.ndarray]:
    """Vertices of each line of a zone GeoPackage's ``lines`` layer (none without the layer)."""
    if gpkg is None or not Path(gpkg).exists():
        return []
    import sqlite3

    import shapely

    from towerpipe.products.gpkg_read import read_towers

    with sqlite3.connect(f"file:{Path(gpkg).resolve()}?mode=ro", uri=True) as db:
        has = db.execute("SELECT 1 FROM gpkg_contents WHERE table_name = ?", (LINES_LAYER,)).fetchone()
    if not has:
        return []
    lines: list[np.ndarray] = []
    for geom in read_towers(gpkg, layer=LINES_LAYER).geometry:
        if geom is not None and not geom.is_empty:
            lines += [np.asarray(part.coords)[:, :2] for part in shapely.get_parts(geom)]
    return lines


def _merge_cost(path: str | os.PathLike[str] | None) -> dict[str, float | None]:
    """``merge_s`` and ``merge_rss_mb`` of a block from its merge's benchmark (None: not recorded)."""
    try:
        b = read_benchmark(path) if path else {}
    except OSError:
        b = {}
    return {"merge_s": b.get("seconds"), "merge_rss_mb": b.get("max_rss_mb")}


def reviewed_flags(doc: Mapping[str, Any], reviews: Mapping[str, str]) -> tuple[list[dict[str, str]], dict[str, str]]:
    """A block QA JSON's flags, without those of the towers an analyst has reviewed.

    Returns
    -------
    open, reviewed
        The flags still to look at, and the reason of each flag of a reviewed tower -> its status.
    """
    reviewed = {
        tower_flag_reason(t["n"], t["tower_id"], reason): reviews[str(t["tower_id"])]
        for t in doc.get("towers") or []
        if str(t["tower_id"]) in reviews
        for reason in t.get("flags") or []
    }
    flags = list(doc.get("flags", []))
    still = [f for f in flags if not (f["code"] == "tower" and f["reason"] in reviewed)]
    return still, {f["reason"]: reviewed[f["reason"]] for f in flags if f not in still}


def zone_index(
    out_html: str | os.PathLike[str],
    block_jsons: Sequence[str | os.PathLike[str]],
    *,
    failures: Mapping[str, str] | None = None,
    zone: str = "",
    out_json: str | os.PathLike[str] | None = None,
    gpkg: str | os.PathLike[str] | None = None,
    block_bounds: Mapping[str, Sequence[float] | None] | None = None,
    vanished: Sequence[Mapping[str, Any]] = (),
    merge_benchmarks: Mapping[str, str | os.PathLike[str]] | None = None,
    n_towers: int | None = None,
    empty: Mapping[str, str] | None = None,
    sources: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """Write the zone's QA index: every block, totals, a map, and the blocks that need a look.

    Parameters
    ----------
    out_html
        Destination page, ``qa/index.html`` of the zone's results (links to the block
        pages are relative to it, each block page is expected next to its JSON; links to
        the products follow :mod:`towerpipe.products.layout`).
    block_jsons
        JSON files written by :func:`towerpipe.products.qa.block.block_report` (missing/unreadable
        ones are listed as failed).
    failures
        Block name → reason, for blocks whose jobs failed (no JSON).
    zone
        Zone name for the title.
    out_json
        Optional JSON with the index numbers.
    gpkg
        The zone's tower GeoPackage: its ``lines`` layer, when it has one, is drawn on the
        overview map (the towers come from the block JSONs), and the page links it. None (or a
        missing file: every block failed) leaves both out and says so. Its review statuses are
        read too: a flag of a tower an analyst has confirmed or rejected there no longer makes its
        block need a look (the block's page, made when the block last ran, still lists it); the
        index shows it as reviewed.
    block_bounds
        Block → ``(xmin, ymin, xmax, ymax)``, for the blocks without a QA JSON (failed) on
        the map; the others take theirs from their JSON.
    vanished
        Registered towers the run did not find again (``tower_id``, ``block``,
        ``centroid_x``, ``centroid_y``, ``height_m``, ``last_seen``, ``vanished_since``,
        ``review_status``; the zone's ``vanished_towers`` layer), listed under the blocks.
    merge_benchmarks
        Block → Snakemake benchmark TSV of its merge (the classified LAZ): its wall time
        and peak memory are listed with the block (the merge runs beside the block's own
        QA page, which reports the jobs before it). A missing file leaves them empty.
    n_towers
        The towers of the zone's GeoPackage: a tower that two overlapping blocks both report
        is one tower there (:func:`towerpipe.products.gpkg_read.concat_towers`) and in the
        totals, though each block lists it. None: the sum over the blocks.
    empty
        Block → file, of the zone's files that hold zero points: listed as blocks that need
        a look (:data:`towerpipe.io.inputs.EMPTY_REASON`), not as failures.
    sources
        Block → its input file (its path under the zone's ``input``), listed with the block
        (also a failed one); a block without one takes it from its QA JSON, if there.

    Returns
    -------
    dict
        ``blocks`` (one dict per block: name, status ``ok``/``look``/``failed``,
        reasons …) and ``totals``.
    """
    out_html = Path(out_html)
    failures = dict(failures or {})
    block_bounds = dict(block_bounds or {})
    blocks: list[dict[str, Any]] = []
    block_docs: dict[str, dict[str, Any]] = {}
    reviews = {str(k): v for k, v in reviewed_towers(gpkg).items()}
    for p in block_jsons:
        p = Path(p)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            blocks.append(
                {
                    "block": p.stem,
                    "status": "failed",
                    "reasons": [f"QA JSON unreadable: {exc}"],
                    "codes": ["failed"],
                    "bounds": block_bounds.get(p.stem),
                }
            )
            continue
        name = d.get("block", p.stem)
        if name in failures:
            continue
        block_docs[name] = d
        href = os.path.relpath(p.parent / d.get("html", p.stem + ".html"), out_html.parent)
        products = [
            {"label": label, "href": layout.link(layout.QA_INDEX, layout.block_product(pattern, name))}
            for label, pattern in (("LAZ", layout.BLOCK_LAZ), ("GeoPackage", layout.BLOCK_GPKG))
        ]
        still, reviewed = reviewed_flags(d, reviews)
        status = d.get("status", "look")
        if status == "look" and reviewed and not still:
            status = "ok"
        blocks.append(
            {
                "block": name,
                "input": (sources or {}).get(name) or ((d.get("stats") or {}).get("source") or {}).get("relpath"),
                "status": status,
                "href": href,
                "products": products,
                "reasons": [f["reason"] for f in still] + [f"{r} (reviewed: {v})" for r, v in reviewed.items()],
                "codes": [f["code"] for f in still] + ["reviewed"] * len(reviewed),
                "n_towers": d.get("n_towers", 0),
                "points": d.get("points"),
                "density": (d.get("density") or {}).get("density_median"),
                "ground_ratio": d.get("ground_ratio"),
                "ground_classified": d.get("ground_classified"),
                "windows_total": d.get("windows_total"),
                "windows_passed_gate": d.get("windows_passed_gate"),
                "tower_prob_mean": d.get("tower_prob_mean"),
                "accuracy": d.get("accuracy"),
                "bounds": d.get("bounds") or block_bounds.get(name),
                **_merge_cost((merge_benchmarks or {}).get(name)),
            }
        )
    for b, reason in failures.items():
        blocks.append(
            {
                "block": b,
                "input": (sources or {}).get(b),
                "status": "failed",
                "reasons": [str(reason)],
                "codes": ["failed"],
                "bounds": block_bounds.get(b),
            }
        )
    for b, source in (empty or {}).items():
        blocks.append(
            {
                "block": b,
                "input": source,
                "status": "look",
                "reasons": [f"{source}: {EMPTY_REASON}"],
                "codes": ["empty"],
                "bounds": None,
            }
        )
    order = {"failed": 0, "look": 1, "ok": 2}
    blocks.sort(key=lambda b: (order.get(b["status"], 1), str(b["block"])))
    done = [b for b in blocks if b["status"] != "failed"]
    acc = [b["accuracy"] for b in done if b.get("accuracy")]
    totals: dict[str, Any] = {
        "blocks": len(blocks),
        "failed": sum(b["status"] == "failed" for b in blocks),
        "look": sum(b["status"] == "look" for b in blocks),
        "ok": sum(b["status"] == "ok" for b in blocks),
        "towers": int(n_towers) if n_towers is not None else int(sum(b.get("n_towers") or 0 for b in done)),
        "points": int(sum(b.get("points") or 0 for b in done)),
        "windows_total": int(sum(b.get("windows_total") or 0 for b in done)),
        "windows_passed_gate": int(sum(b.get("windows_passed_gate") or 0 for b in done)),
        "precision": None,
        "recall": None,
    }
    if acc:
        tp, fp, fn = (sum(a[k] for a in acc) for k in ("tp", "fp", "fn"))
        totals["precision"] = tp / (tp + fp) if tp + fp else None
        totals["recall"] = tp / (tp + fn) if tp + fn else None
    s = (
        f"{totals['towers']} tower{'s' if totals['towers'] != 1 else ''} found in {totals['blocks']} block"
        f"{'s' if totals['blocks'] != 1 else ''}"
    )
    if totals["failed"]:
        s += f"; {totals['failed']} failed"
    if totals["look"]:
        s += f"; {totals['look']} need{'s' if totals['look'] == 1 else ''} a look"
    if not totals["failed"] and not totals["look"]:
        s += "; nothing to check"
    totals["summary"] = s + "."
    totals["vanished_towers"] = len(vanished)
    tower_xy = [(t["x"], t["y"]) for b in block_docs.values() for t in b.get("towers") or []]
    lines = _gpkg_lines(gpkg)
    doc = jsonable(
        {
            "zone": zone,
            "blocks": blocks,
            "totals": totals,
            "n_lines": len(lines),
            "vanished_towers": list(vanished),
            "user_classes": zone_user_classes(block_docs.values()),
            "generated_at": datetime.now(UTC).replace(microsecond=0).isoformat(),
        }
    )
    if out_json is not None:
        write_text_atomic(out_json, json.dumps(doc, indent=1))
    zone_svg = Markup(zone_map(doc["blocks"], tower_xy, lines)) if any(b.get("bounds") for b in doc["blocks"]) else None
    # the zone's GeoPackage is written when a block finished (none when every block failed)
    links = (
        [{"label": f"zone towers ({layout.ZONE_GPKG})", "href": layout.link(layout.QA_INDEX, layout.ZONE_GPKG)}]
        if gpkg is not None and Path(gpkg).exists()
        else []
    )
    render("index.html", out_html, d=doc, zone_svg=zone_svg, links=links)
    return doc
