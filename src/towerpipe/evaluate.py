"""Evaluating a processed zone against its truth (synthetic zones, or labelled blocks).

Tower level: predicted towers (``results/<zone>/towers.gpkg``) matched one-to-one
to true towers (a match = footprints intersect or centroids within 5 m), giving
precision and recall, plus the number of true towers claimed by more than one
prediction (a tower reported twice). Point level: the classified blocks'
``Classification == 15`` against the input labels (class 15), as IoU.

``towerpipe evaluate --zone-dir data/holdout --results results/holdout``
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import geopandas as gpd
import laspy
import numpy as np

from towerpipe.errors import InputError
from towerpipe.lasio import find_blocks, laz_backend

TOWER_CLASS = 15


def point_confusion(input_block: str | os.PathLike[str], classified_block: str | os.PathLike[str]) -> dict[str, int]:
    """Tower point counts: true positives, false positives, false negatives of one block."""
    truth = np.asarray(laspy.read(input_block, laz_backend=laz_backend()).classification) == TOWER_CLASS
    pred = np.asarray(laspy.read(classified_block, laz_backend=laz_backend()).classification) == TOWER_CLASS
    if truth.shape != pred.shape:
        raise InputError(classified_block, f"holds {pred.size} points, its input {truth.size}")
    return {"tp": int((truth & pred).sum()), "fp": int((~truth & pred).sum()), "fn": int((truth & ~pred).sum())}


def evaluate_zone(input_dir: str | os.PathLike[str], results_dir: str | os.PathLike[str], *,
                  truth_gpkg: str | os.PathLike[str] | None = None, max_dist: float = 5.0,
                  out_json: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """Tower precision/recall and point IoU of a processed zone.

    Parameters
    ----------
    input_dir
        The zone's input directory (labelled blocks; for synthetic zones also
        ``towers_truth.gpkg``).
    results_dir
        ``results/<zone>/``.
    truth_gpkg
        True tower footprints (default: ``input_dir/towers_truth.gpkg``).
    """
    from towerpipe.gpkg import read_towers
    from towerpipe.towers import match_towers

    input_dir, results_dir = Path(input_dir), Path(results_dir)
    truth_path = Path(truth_gpkg) if truth_gpkg else input_dir / "towers_truth.gpkg"
    truth = gpd.read_file(truth_path, layer="towers")
    pred = read_towers(results_dir / "towers.gpkg")
    m = match_towers(pred, truth, max_dist=max_dist)
    ids = pred["tower_id"].tolist() if len(pred) else []
    # a true tower hit by several predictions = reported twice (the one-to-one match keeps one)
    claimed = np.zeros(len(truth), int)
    for geom, c in zip(pred.geometry, pred.geometry.centroid):
        hit = truth.geometry.intersects(geom) | (truth.geometry.centroid.distance(c) <= max_dist)
        claimed += hit.to_numpy().astype(int)
    tp = fp = fn = 0
    per_block = {}
    for name, path in find_blocks(input_dir).items():
        out = results_dir / "blocks" / f"{name}.laz"
        c = point_confusion(path, out)
        per_block[name] = c
        tp, fp, fn = tp + c["tp"], fp + c["fp"], fn + c["fn"]
    iou = tp / (tp + fp + fn) if (tp + fp + fn) else float("nan")
    res = {
        "towers_true": int(len(truth)), "towers_predicted": int(len(pred)),
        "tower_precision": m["precision"], "tower_recall": m["recall"], "tower_f1": m.get("f1"),
        "towers_reported_twice": int((claimed > 1).sum()), "duplicate_ids": len(ids) - len(set(ids)),
        "point_iou_tower": iou, "points": {"tp": tp, "fp": fp, "fn": fn}, "per_block": per_block,
        "unmatched_truth": [str(t) for t in m.get("unmatched_truth", [])],
        "unmatched_pred": [str(t) for t in m.get("unmatched_pred", [])],
    }
    if out_json:
        Path(out_json).write_text(json.dumps(res, indent=1, default=str))
    return res


def record_reference(model_dir: str | os.PathLike[str], result: dict[str, Any], zone_config: str) -> None:
    """Store a zone's evaluation in a model card (``metrics.reference_zone``).

    CI regenerates that zone from ``zone_config`` (deterministic by seed), reruns it
    with the model and checks the figures are reproduced.
    """
    from towerpipe import modelcard

    card = modelcard.read_card(model_dir)
    keep = ("towers_true", "towers_predicted", "tower_precision", "tower_recall", "tower_f1",
            "towers_reported_twice", "point_iou_tower")
    card.setdefault("metrics", {})["reference_zone"] = {"zone_config": zone_config, **{k: result[k] for k in keep}}
    modelcard.write_card(Path(model_dir), card)


def _cli(args: argparse.Namespace) -> int:
    res = evaluate_zone(args.zone_dir, args.results, truth_gpkg=args.truth, out_json=args.json)
    if args.record_in:
        record_reference(args.record_in, res, args.zone_config)
    print(f"towers: {res['towers_predicted']} predicted, {res['towers_true']} true; "
          f"precision {res['tower_precision']:.3f} recall {res['tower_recall']:.3f}; "
          f"reported twice {res['towers_reported_twice']}; point IoU (tower) {res['point_iou_tower']:.3f}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="tower precision/recall and point IoU of a processed zone against truth")
    p.add_argument("--zone-dir", required=True, help="the zone's input directory (labelled blocks)")
    p.add_argument("--results", required=True, help="results/<zone>/")
    p.add_argument("--truth", help="true tower footprints (default: ZONE_DIR/towers_truth.gpkg)")
    p.add_argument("--json", help="write the figures here")
    p.add_argument("--record-in", metavar="MODEL_DIR", help="store the figures in this model's card")
    p.add_argument("--zone-config", default=".test/config/config.yaml", help="config that defines the zone")
    p.set_defaults(func=_cli)
