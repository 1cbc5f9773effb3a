"""Evaluating a processed zone against its truth (synthetic zones, or labelled blocks).

Tower level: predicted towers (``results/<zone>/towers.gpkg``) matched one-to-one
to true towers (a match = footprints intersect or centroids within 5 m), giving
precision and recall, plus the number of true towers claimed by more than one
prediction (a tower reported twice). Point level: the classified blocks'
``Classification == 15`` against the input labels (class 15), as IoU.

``towerpipe evaluate --zone-dir data/holdout --results results/holdout``

Window level (the paper's metrics, issue #4): :func:`evaluate_windows` builds windows
from a held-out zone's labelled tiles exactly as for training (same dataset
configuration as the model's card) and reports the classifier's F1 and the segmenter's
IoU tower / IoU background / mIoU on all points of the positive windows.
``towerpipe evaluate-windows --model models/towerpipe-full-v2 --tiles 'work/holdout/tiles/*/*.npz'``
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import geopandas as gpd
import laspy
import numpy as np

from towerpipe import classes
from towerpipe.errors import InputError
from towerpipe.io.inputs import find_blocks
from towerpipe.io.las import laz_backend


def _read_pair(
    input_block: str | os.PathLike[str], classified_block: str | os.PathLike[str]
) -> tuple[laspy.LasData, np.ndarray]:
    """An input block and the classification of its classified copy, each decoded once."""
    src = laspy.read(input_block, laz_backend=laz_backend())
    pred = np.asarray(laspy.read(classified_block, laz_backend=laz_backend()).classification)
    if pred.size != len(src.points):
        raise InputError(classified_block, f"holds {pred.size} points, its input {len(src.points)}")
    return src, pred


def _confusion(truth_class: np.ndarray, pred_class: np.ndarray) -> dict[str, int]:
    truth, pred = truth_class == classes.TOWER, pred_class == classes.TOWER
    return {"tp": int((truth & pred).sum()), "fp": int((~truth & pred).sum()), "fn": int((truth & ~pred).sum())}


def point_confusion(input_block: str | os.PathLike[str], classified_block: str | os.PathLike[str]) -> dict[str, int]:
    """Tower point counts: true positives, false positives, false negatives of one block."""
    src, pred = _read_pair(input_block, classified_block)
    return _confusion(np.asarray(src.classification), pred)


def zone_points(
    input_dir: str | os.PathLike[str], results_dir: str | os.PathLike[str]
) -> tuple[dict[str, dict[str, int]], dict[str, np.ndarray]]:
    """Per-block tower point confusion, and the points the pipeline labelled 15, in one pass.

    Returns
    -------
    tuple
        ``(per_block, labelled)``: block name -> :func:`point_confusion` counts; and
        ``x``, ``y`` and input ``classification`` of every point labelled 15 in
        ``results_dir/blocks`` (for :func:`false_tower_sources`).
    """
    per_block: dict[str, dict[str, int]] = {}
    parts: dict[str, list[np.ndarray]] = {"x": [], "y": [], "classification": []}
    for name, path in find_blocks(input_dir).items():
        src, pred = _read_pair(path, Path(results_dir) / "blocks" / f"{name}.laz")
        truth = np.asarray(src.classification)
        per_block[name] = _confusion(truth, pred)
        sel = np.flatnonzero(pred == classes.TOWER)
        parts["x"].append(np.asarray(src.x)[sel])
        parts["y"].append(np.asarray(src.y)[sel])
        parts["classification"].append(truth[sel])
    labelled = {k: np.concatenate(v) if v else np.empty(0) for k, v in parts.items()}
    return per_block, labelled


def false_tower_sources(false_towers: gpd.GeoDataFrame, labelled: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """What the input labels say the points of each false tower are.

    Parameters
    ----------
    false_towers
        Predicted towers that matched no true tower (``towers`` layer rows).
    labelled
        The points labelled 15 by the pipeline (second item of :func:`zone_points`).

    Returns
    -------
    list of dict
        Per false tower: ``tower_id``, ``height_m``, ``n_points``, ``prob_mean`` and
        ``input_classes`` (input class -> count of its points labelled 15 by the pipeline
        inside the footprint, buffered by 0.5 m).
    """
    import shapely

    rows = []
    for _, t in false_towers.iterrows():
        inside = shapely.contains_xy(shapely.buffer(t.geometry, 0.5), labelled["x"], labelled["y"])
        cls, n = np.unique(labelled["classification"][inside], return_counts=True)
        rows.append(
            {
                "tower_id": str(t["tower_id"]),
                "height_m": round(float(t["height_m"]), 1),
                "n_points": int(t["n_points"]),
                "prob_mean": round(float(t["prob_mean"]), 3),
                "input_classes": {int(c): int(k) for c, k in zip(cls, n)},
            }
        )
    return rows


def hard_negatives(input_dir: str | os.PathLike[str], pred: gpd.GeoDataFrame, max_dist: float = 5.0) -> dict:
    """The hard negatives a generated zone records (``negatives`` of its ``synth_meta.json``:
    cranes, masts, turbines, chimneys, poles) by kind: how many stand in the zone, and on how
    many a reported tower stands (its footprint within ``max_dist`` m of the object's base).

    Returns ``{}`` for a zone that records none (a real zone, or one generated without them).
    """
    import shapely

    from towerpipe.synth.truth import META_JSON

    path = Path(input_dir) / META_JSON
    negs = (json.loads(path.read_text()).get("negatives") or []) if path.exists() else []
    out: dict[str, dict[str, int]] = {}
    for n in negs:
        d = out.setdefault(str(n["kind"]), {"objects": 0, "reported": 0})
        d["objects"] += 1
        if len(pred) and float(pred.geometry.distance(shapely.Point(n["x"], n["y"])).min()) <= max_dist:
            d["reported"] += 1
    return out


def evaluate_zone(
    input_dir: str | os.PathLike[str],
    results_dir: str | os.PathLike[str],
    *,
    truth_gpkg: str | os.PathLike[str] | None = None,
    max_dist: float = 5.0,
    out_json: str | os.PathLike[str] | None = None,
    min_truth_points: int = 0,
) -> dict[str, Any]:
    """Tower precision/recall and point IoU of a processed zone.

    Parameters
    ----------
    input_dir
        The zone's input directory (labelled blocks; for synthetic zones also
        ``towers_truth.gpkg``).
    results_dir
        ``results/<zone>/``.
    truth_gpkg
        True tower footprints (default: ``input_dir/towers_truth.gpkg``, else the towers the
        blocks label 15: :func:`towerpipe.evaluation.truth.zone_truth`).
    min_truth_points
        True towers with fewer points (``n_points`` of the truth file) are left out of
        the tower figures, and a prediction matching one is not counted as false: the
        paper drops towers under 20 points from its data. 0 evaluates every tower.
    """
    from towerpipe.evaluation.truth import zone_truth
    from towerpipe.products.gpkg_read import read_towers
    from towerpipe.towers.matching import match_towers

    input_dir, results_dir = Path(input_dir), Path(results_dir)
    truth = zone_truth(input_dir, truth_gpkg, min_points=max(1, int(min_truth_points)))
    pred = read_towers(results_dir / "towers.gpkg")
    ignored = 0
    if min_truth_points and "n_points" in truth.columns:
        small = truth["n_points"].to_numpy() < int(min_truth_points)
        if small.any() and len(pred):
            hits = match_towers(pred, truth[small], max_dist=max_dist)["matches"]
            drop = {h["pred"] for h in hits}
            ignored = len(drop)
            pred = pred[~pred["tower_id"].astype(str).isin(drop)]
        truth = truth[~small]
    m = match_towers(pred, truth, max_dist=max_dist)
    ids = pred["tower_id"].tolist() if len(pred) else []
    # a true tower hit by several predictions = reported twice (the one-to-one match keeps one)
    claimed = np.zeros(len(truth), int)
    for geom, c in zip(pred.geometry, pred.geometry.centroid):
        hit = truth.geometry.intersects(geom) | (truth.geometry.centroid.distance(c) <= max_dist)
        claimed += hit.to_numpy().astype(int)
    per_block, labelled = zone_points(input_dir, results_dir)
    tp, fp, fn = (sum(c[k] for c in per_block.values()) for k in ("tp", "fp", "fn"))
    iou = tp / (tp + fp + fn) if (tp + fp + fn) else float("nan")
    res = {
        "towers_true": int(len(truth)),
        "towers_predicted": int(len(pred)),
        "tower_precision": m["precision"],
        "tower_recall": m["recall"],
        "tower_f1": m.get("f1"),
        "towers_reported_twice": int((claimed > 1).sum()),
        "duplicate_ids": len(ids) - len(set(ids)),
        "point_iou_tower": iou,
        "min_truth_points": int(min_truth_points),
        "predictions_on_small_towers_ignored": ignored,
        "points": {"tp": tp, "fp": fp, "fn": fn},
        "per_block": per_block,
        "unmatched_truth": [str(t) for t in m.get("unmatched_truth", [])],
        "unmatched_pred": [str(t) for t in m.get("unmatched_pred", [])],
    }
    false = pred[pred["tower_id"].astype(str).isin(res["unmatched_pred"])] if len(pred) else pred
    res["false_towers"] = false_tower_sources(false, labelled)
    res["hard_negatives"] = hard_negatives(input_dir, pred, max_dist)
    if out_json:
        Path(out_json).write_text(json.dumps(res, indent=1, default=str))
    return res


def record_reference(model_dir: str | os.PathLike[str], result: dict[str, Any], zone_config: str) -> None:
    """Store a zone's evaluation in a model card (``metrics.reference_zone``).

    CI regenerates that zone from ``zone_config`` (deterministic by seed), reruns it
    with the model and checks the figures are reproduced.
    """
    from towerpipe.model import cards as modelcard

    card = modelcard.read_card(model_dir)
    keep = (
        "towers_true",
        "towers_predicted",
        "tower_precision",
        "tower_recall",
        "tower_f1",
        "towers_reported_twice",
        "point_iou_tower",
    )
    card.setdefault("metrics", {})["reference_zone"] = {"zone_config": zone_config, **{k: result[k] for k in keep}}
    modelcard.write_card(Path(model_dir), card)


def evaluate_windows(
    model_dir: str | os.PathLike[str], tile_paths: list[str], *, dataset_config: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Window-level metrics of a model bundle on labelled tiles of a held-out zone.

    Parameters
    ----------
    model_dir
        A model bundle directory.
    tile_paths
        Tile files (``work/<zone>/tiles/<block>/<tile>.npz``) of a zone never used in training.
    dataset_config
        Overrides of the window-building configuration; default: the one recorded in the
        model card (so the mix of positives, hard and tall negatives is the training one).

    Returns
    -------
    dict
        ``classifier`` (F1, precision, recall, accuracy, n, positives), ``segmenter``
        (IoU tower, IoU background, mIoU, points, windows), ``windows``, ``towers``.

    Raises
    ------
    InputError
        Some of the tiles are among those the model was trained on (its card's
        ``training_data.tiles``, paths as the training saw them, relative to the repository).
    """
    from towerpipe.model.bundle import load_bundle
    from towerpipe.training.dataset import build_windows
    from towerpipe.training.metrics import classification_metrics, predict_windows, segment_windows_metrics

    bundle = load_bundle(model_dir)
    paths = sorted(str(p) for p in tile_paths)
    if not paths:
        raise InputError(str(model_dir), "no tile files to evaluate on; run the zone's preprocessing first")
    trained_on = {os.path.realpath(t) for t in (bundle.card.get("training_data") or {}).get("tiles") or ()}
    seen = [p for p in paths if os.path.realpath(p) in trained_on]
    if seen:
        raise InputError(
            seen[0],
            f"{len(seen)} of the {len(paths)} tiles are among those {bundle.name} v{bundle.version} was trained "
            "on (its card's training_data.tiles): figures on them are not held-out; give the tiles of a zone "
            "it never saw",
        )
    recorded = bundle.card.get("config") or {}
    cfg = dict(recorded.get("dataset") or {})
    cfg.update(dataset_config or {})
    blocks = sorted({Path(p).parent.name for p in paths})
    cfg["split"] = {"test": blocks}
    ws = build_windows(paths, cfg)
    idx = ws.indices("test")
    fs = bundle.feature_set
    thr = float((recorded.get("train") or {}).get("threshold", 0.5))
    clf = classification_metrics(predict_windows(bundle.classifier, ws, idx, fs), ws.label[idx], thr)
    seg = segment_windows_metrics(bundle.segmenter, ws, idx, fs, thr, bundle.chunk)
    return {
        "model": bundle.name,
        "version": bundle.version,
        "tiles": paths,
        "windows": int(len(idx)),
        "towers": int(ws.meta["towers"]),
        "classifier": clf,
        "segmenter": seg,
    }


def record_windows(model_dir: str | os.PathLike[str], result: dict[str, Any], zone: str) -> None:
    """Store window-level held-out metrics in a model card (``metrics.holdout_windows.<zone>``)."""
    from towerpipe.model import cards as modelcard

    card = modelcard.read_card(model_dir)
    card.setdefault("metrics", {}).setdefault("holdout_windows", {})[zone] = {
        "windows": result["windows"],
        "towers": result["towers"],
        "classifier": result["classifier"],
        "segmenter": result["segmenter"],
    }
    modelcard.write_card(Path(model_dir), card)


def _cli_windows(args: argparse.Namespace) -> int:
    import glob

    res = evaluate_windows(args.model, sorted(glob.glob(args.tiles, recursive=True)))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1, default=str))
    if args.record_in_card:
        record_windows(args.model, res, args.zone or args.tiles)
    c, s = res["classifier"], res["segmenter"]
    print(
        f"{res['model']} v{res['version']}: {res['windows']} windows, {res['towers']} towers; classifier F1 "
        f"{c['f1']:.3f} (P {c['precision']:.3f} R {c['recall']:.3f}); segmenter IoU tower {s['iou_tower']:.3f} "
        f"IoU background {s['iou_background']:.3f} mIoU {s['miou']:.3f}"
    )
    return 0


def _figure(value: float | None) -> str:
    """A ratio to three decimals, ``n/a`` where it is undefined (no tower true or predicted)."""
    return "n/a" if value is None else f"{value:.3f}"


def summary_line(res: Mapping[str, Any]) -> str:
    """One line of :func:`evaluate_zone`'s figures (``towerpipe evaluate``)."""
    return (
        f"towers: {res['towers_predicted']} predicted, {res['towers_true']} true; "
        f"precision {_figure(res['tower_precision'])} recall {_figure(res['tower_recall'])}; "
        f"reported twice {res['towers_reported_twice']}; point IoU (tower) {_figure(res['point_iou_tower'])}"
    )


def _cli(args: argparse.Namespace) -> int:
    res = evaluate_zone(
        args.zone_dir, args.results, truth_gpkg=args.truth, out_json=args.json, min_truth_points=args.min_truth_points
    )
    if args.record_in:
        record_reference(args.record_in, res, args.zone_config)
    print(summary_line(res))
    for t in res["false_towers"]:
        print(
            f"false tower {t['tower_id']}: {t['height_m']} m, {t['n_points']} points, mean probability "
            f"{t['prob_mean']}; input classes of its points {t['input_classes']}"
        )
    if res["hard_negatives"]:
        kinds = ", ".join(
            f"{k} {d['objects']} ({d['reported']} reported)" for k, d in sorted(res["hard_negatives"].items())
        )
        print(f"hard negatives of the generated zone: {kinds}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="tower precision/recall and point IoU of a processed zone against truth")
    p.add_argument("--zone-dir", required=True, help="the zone's input directory (labelled blocks)")
    p.add_argument("--results", required=True, help="results/<zone>/")
    p.add_argument(
        "--truth",
        help="true tower footprints (default: ZONE_DIR/towers_truth.gpkg, else the towers its blocks label 15)",
    )
    p.add_argument("--json", help="write the figures here")
    p.add_argument(
        "--min-truth-points",
        type=int,
        default=0,
        help="leave out true towers with fewer points (the paper drops towers under 20 points)",
    )
    p.add_argument("--record-in", metavar="MODEL_DIR", help="store the figures in this model's card")
    p.add_argument("--zone-config", default=".test/config/config.yaml", help="config that defines the zone")
    p.set_defaults(func=_cli)
    p = sub.add_parser("evaluate-windows", help="window-level F1 / IoU of a model on a held-out zone's tiles")
    p.add_argument("--model", required=True, help="model bundle directory")
    p.add_argument("--tiles", required=True, help="glob of the zone's tile files, e.g. 'work/holdout/tiles/*/*.npz'")
    p.add_argument("--json", help="write the figures here")
    p.add_argument(
        "--record-in-card", action="store_true", help="store them in the model card (metrics.holdout_windows)"
    )
    p.add_argument("--zone", help="zone name recorded with the figures")
    p.set_defaults(func=_cli_windows)
