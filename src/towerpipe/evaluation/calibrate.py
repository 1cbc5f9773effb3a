"""Calibrating the inference and tower thresholds on labelled zones.

The thresholds of ``inference`` and ``towers`` (views, point threshold, clustering
threshold, ``min_core_prob``) are set on calibration zones, never on held-out ones. A
full pipeline run per candidate costs a minute per zone; most candidates share their
predictions. :func:`sweep` therefore predicts each tile of a zone once per number of
views (:func:`towerpipe.evaluation.predcache.zone_predictions`, cached under
``<workdir>/<zone>/calibrate/``), then, per candidate, finds the
towers of the whole zone at once (:func:`towerpipe.towers.extract.extract_towers` with the
zone's tiles as conductor context, the other tower rules from the config) and scores
them against the input labels: tower precision / recall (as ``towerpipe evaluate``) and
point IoU of class 15.

The zone must have been preprocessed (``snakemake --cores 2 results/<zone>/``). On a
whole zone the towers are built as the pipeline builds them block by block, so the
figures of the configured candidate are the pipeline's (tested on the CI zone).

``towerpipe calibrate --zones calib,calib2,calib3 --tta 1,2 --point-threshold 0.4,0.5,0.6``
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.config import InferenceConfig
from towerpipe.errors import InputError
from towerpipe.evaluation.predcache import zone_predictions, zone_tiles
from towerpipe.evaluation.truth import zone_labels

__all__ = [
    "Candidate",
    "score_zone",
    "sweep",
    "sweep_table",
    "zone_model",
    "zone_survey",
    "zone_towers",
]

#: One candidate: (views, towers.threshold, inference.threshold, towers.min_core_prob), optionally
#: followed by inference.gate, towers.min_wire_support and towers.rescue_threshold (default: the config's).
Candidate = tuple[float, ...]

_UNBOUNDED = (-1e18, -1e18, 1e18, 1e18)
#: A true tower's neighbourhood (m around its footprint) where its segmented points are looked for.
NEAR_TOWER_M = 1.0


def zone_survey(work: str | os.PathLike[str], zone: str) -> list[list[float]]:
    """The measured bounds of the zone's blocks (its plan, written by the pipeline's split): where
    the data is, as the towers jobs see it (:func:`score_zone`'s ``survey``)."""
    plan = Path(work, zone, "plan.json")
    if not plan.exists():
        raise InputError(plan, f"zone {zone!r} has no plan yet; run `snakemake --cores 2 results/{zone}/` first")
    blocks = json.loads(plan.read_text())["blocks"]
    return [list(map(float, b["bounds"])) for b in blocks.values() if b.get("bounds")]


def zone_towers(
    preds: Sequence[Any],
    tile_paths: Sequence[str | os.PathLike[str]],
    towers: Mapping[str, Any],
    *,
    point_threshold: float,
    survey: Sequence[Sequence[float]],
    zone: str,
    crs: Any,
    trace: list[dict[str, Any]] | None = None,
) -> Any:
    """The towers of a whole zone at once, as its towers jobs find them block by block (the config's
    ``towers`` rules; the tiles as context: :func:`score_zone`; ``trace``: see ``extract_towers``)."""
    from towerpipe.config import TowersConfig
    from towerpipe.towers.coverage import TileContext
    from towerpipe.towers.extract import extract_towers

    return extract_towers(
        preds,
        zone,
        _UNBOUNDED,
        TowersConfig.from_config({"towers": dict(towers)}),
        zone=zone,
        point_threshold=point_threshold,
        context=TileContext(
            [str(p) for p in tile_paths], survey=survey, min_line_share=float(towers["wire_line_coverage"])
        ),
        model_meta={},
        crs=crs,
        trace=trace,
    )


def score_zone(
    preds: Sequence[Any],
    tile_paths: Sequence[str],
    truth,
    labels: Mapping[str, np.ndarray],
    *,
    threshold: float,
    point_threshold: float,
    min_core_prob: float,
    towers: Mapping[str, Any],
    survey: Sequence[Sequence[float]],
    zone: str = "zone",
    min_truth_points: int = 0,
) -> dict[str, Any]:
    """Towers of a whole zone from its predictions, scored against its labels.

    Parameters
    ----------
    preds
        Prediction files (or loaded predictions) of every tile of the zone.
    tile_paths
        The zone's tiles (conductor support context).
    survey
        The measured bounds of the zone's blocks (:func:`zone_survey`): where the data is, as
        the towers jobs see it (``towers.wire_line_coverage``; see
        :class:`towerpipe.towers.coverage.TileContext`). Required: without it a tower through which a
        line could leave the data unseen would be judged on the rest, which the pipeline never does.
    truth
        True tower footprints (GeoDataFrame, layer ``towers`` of ``towers_truth.gpkg``).
    labels
        Block name -> indices of its class-15 input points.
    threshold, point_threshold, min_core_prob
        The candidate (``towers.threshold``, ``inference.threshold``, ``towers.min_core_prob``).
    towers
        The config's ``towers`` section: the other rules (every key of
        :class:`towerpipe.config.TowersConfig` but the candidate's).
    min_truth_points
        True towers with fewer points are left out of the tower scores, and a prediction
        matching one is not a false tower (the paper's floor: 20 points).

    Returns
    -------
    dict
        ``precision``, ``recall``, ``f1``, ``towers``, ``point_iou``, ``tp``, ``fp``, ``fn``
        (tower points), ``towers_tp``, ``towers_fp``, ``towers_fn``, ``true_towers``,
        ``towers_tp_min_points`` and ``true_towers_min_points`` (the true towers of
        ``towers.min_points`` points or more, found and in all: the paper's floor, as
        ``towerpipe trace`` lists them; the scores above count every true tower),
        ``gate_recall`` (share of the true towers that some window passing the gate
        covers: they have segmented points) and ``false_towers`` (height, points, footprint centroid).
    """
    from towerpipe.towers.matching import match_towers, tower_ids

    rules = {**towers, "threshold": threshold, "min_core_prob": min_core_prob}
    found = zone_towers(
        preds, tile_paths, rules, point_threshold=point_threshold, survey=survey, zone=zone, crs=truth.crs
    )
    gdf = found.towers
    chosen: dict[str, list[np.ndarray]] = {}
    for blocks, idx in found.members.values():
        blocks = np.asarray(blocks).astype(str)
        for b in np.unique(blocks):
            chosen.setdefault(str(b), []).append(np.asarray(idx)[blocks == b])
    tp = fp = fn = 0
    for name in sorted(set(labels) | set(chosen)):
        pred = np.unique(np.concatenate(chosen.get(name) or [np.empty(0, np.int64)]))
        true = labels.get(name, np.empty(0, np.int64))
        hit = int(np.intersect1d(pred, true, assume_unique=True).size)
        tp, fp, fn = tp + hit, fp + pred.size - hit, fn + true.size - hit
    if min_truth_points and "n_points" in truth.columns and len(truth):
        small = truth["n_points"].to_numpy() < int(min_truth_points)
        if small.any() and len(gdf):
            hits = {str(h["pred"]) for h in match_towers(gdf, truth[small], max_dist=5.0)["matches"]}
            gdf = gdf[~gdf["tower_id"].astype(str).isin(hits)]
        truth = truth[~small]
    m = match_towers(gdf, truth, max_dist=5.0)
    false = gdf[gdf["tower_id"].astype(str).isin([str(i) for i in m["unmatched_pred"]])] if len(gdf) else gdf
    # the towers of towers.min_points points or more (the paper's floor: 20), as `towerpipe trace` counts them
    big = np.ones(len(truth), bool)
    if "n_points" in truth.columns:
        big = truth["n_points"].to_numpy() >= int(towers["min_points"])
    matched = {h["truth"] for h in m["matches"]}
    return {
        "precision": m["precision"],
        "recall": m["recall"],
        "f1": m["f1"],
        "towers": int(len(gdf)),
        "point_iou": tp / (tp + fp + fn) if tp + fp + fn else float("nan"),
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "towers_tp": m["tp"],
        "towers_fp": m["fp"],
        "towers_fn": m["fn"],
        "true_towers": int(len(truth)),
        "towers_tp_min_points": int(sum(t in matched for t in np.asarray(tower_ids(truth), dtype=object)[big])),
        "true_towers_min_points": int(big.sum()),
        "gate_recall": gate_recall(preds, truth),
        "false_towers": false_tower_rows(false),
    }


def false_tower_rows(false) -> list[dict[str, float | int]]:
    """Height, points and footprint centre (x, y, the zone's CRS) of each false tower, to find it
    in the zone's blocks."""
    return [
        {
            "height_m": round(float(r["height_m"]), 1),
            "n_points": int(r["n_points"]),
            "x": round(float(r.geometry.centroid.x), 1),
            "y": round(float(r.geometry.centroid.y), 1),
        }
        for _, r in false.iterrows()
    ]


def gate_recall(preds: Sequence[Any], truth) -> float | None:
    """Share of the true towers (footprint + 1 m) holding a segmented point, i.e. reached by the gate."""
    import shapely

    from towerpipe.io.predictions import load_pred

    if not len(truth):
        return None
    loaded = [load_pred(p) if isinstance(p, (str, os.PathLike)) else p for p in preds]
    x = np.concatenate([np.asarray(p.arrays["x"]) for p in loaded]) if loaded else np.empty(0)
    y = np.concatenate([np.asarray(p.arrays["y"]) for p in loaded]) if loaded else np.empty(0)
    hit = [bool(shapely.contains_xy(shapely.buffer(g, NEAR_TOWER_M), x, y).any()) for g in truth.geometry]
    return float(np.mean(hit))


#: The tower counts of :func:`score_zone` that :func:`sweep` sums over the zones of a candidate
#: (``total_<key>``): found, false and true towers, and found and true among those of
#: ``towers.min_points`` points or more.
TOTALS = ("towers_tp", "towers_fp", "true_towers", "towers_tp_min_points", "true_towers_min_points")


def sweep(
    zones: Mapping[str, str | os.PathLike[str]],
    candidates: Sequence[Candidate],
    *,
    work: str,
    model: str | Mapping[str, str],
    inference: Mapping[str, Any],
    towers: Mapping[str, Any],
) -> list[dict[str, Any]]:
    """Score every candidate on every zone.

    Parameters
    ----------
    zones
        Zone name -> its input directory (labelled blocks and ``towers_truth.gpkg``).
    candidates
        ``(views, towers.threshold, inference.threshold, towers.min_core_prob[, inference.gate[,
        towers.min_wire_support[, towers.rescue_threshold]]])`` tuples (the last three default to
        the config's).
    work, model, inference, towers
        Workdir, model bundle directory (or zone -> its model directory) and the config's sections.

    Returns
    -------
    list of dict
        One row per candidate: the candidate, per-zone :func:`score_zone` figures, their
        :data:`TOTALS` summed over the zones (``total_towers_tp``, ...), ``mean_point_iou`` and
        ``mean_f1`` (tower F1, 0 where a zone has none) over the zones.
    """

    from towerpipe.io.predictions import load_pred

    data = {}
    for zone, input_dir in zones.items():
        data[zone] = (
            *zone_labels(input_dir),
            [str(p) for p in zone_tiles(work, zone)],
            zone_survey(work, zone),
        )
    settings = InferenceConfig.from_config({"inference": inference})
    preds: dict[tuple[str, int, float], list[Any]] = {}
    rows = []
    for cand in candidates:
        tta, thr, pthr, mcp, *rest = cand
        tta = int(tta)
        gate = float(rest[0]) if rest else float(inference["gate"])
        wire = float(rest[1]) if len(rest) > 1 else float(towers["min_wire_support"])
        rescue = float(rest[2]) if len(rest) > 2 else float(towers["rescue_threshold"])
        row: dict[str, Any] = {
            "tta": tta,
            "threshold": thr,
            "point_threshold": pthr,
            "min_core_prob": mcp,
            "gate": gate,
            "min_wire_support": wire,
            "rescue_threshold": rescue,
        }
        for zone, (truth, labels, tiles, survey) in data.items():
            if (zone, tta, gate) not in preds:
                zm = model if isinstance(model, (str, os.PathLike)) else model[zone]
                cand_settings = dataclasses.replace(settings, tta=tta, gate=gate)
                preds[(zone, tta, gate)] = [
                    load_pred(p) for p in zone_predictions(work, zone, zm, cand_settings, towers["verifier"])
                ]
            row[zone] = score_zone(
                preds[(zone, tta, gate)],
                tiles,
                truth,
                labels,
                threshold=thr,
                point_threshold=pthr,
                min_core_prob=mcp,
                towers={**towers, "min_wire_support": wire, "rescue_threshold": rescue},
                zone=zone,
                survey=survey,
            )
        for key in TOTALS:
            row[f"total_{key}"] = int(sum(row[z][key] for z in data))
        row["mean_point_iou"] = float(np.mean([row[z]["point_iou"] for z in data]))
        row["mean_f1"] = float(np.mean([row[z]["f1"] or 0.0 for z in data]))
        rows.append(row)
    return rows


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v.strip()]


def zone_model(work: str | os.PathLike[str], zone: str, spec: str) -> str:
    """The model a zone's pipeline run used: its choice file for ``auto``, else the named model."""
    from towerpipe.model.choice import AUTO, read_choice, resolve_model

    if spec != AUTO:
        return str(resolve_model(spec))
    path = Path(work, zone, "model.json")
    if not path.exists():
        raise InputError(
            path,
            f"zone {zone!r} has no model choice yet; run `snakemake --cores 2 results/{zone}/` first, or pass --model",
        )
    return str(read_choice(path)["path"])


def _cli(args: argparse.Namespace) -> int:
    from towerpipe.config import SCHEMA_FILE, load_yaml, repo_root, update_config, validate_config

    cfg: dict[str, Any] = {}
    for path in args.config:  # later files win, merged as Snakemake merges them
        update_config(cfg, load_yaml(path))
    validate_config(cfg, repo_root() / SCHEMA_FILE)  # every default from the schema
    inference, towers = dict(cfg["inference"]), dict(cfg["towers"])
    work = args.workdir or cfg["workdir"]
    zones, models = {}, {}
    for z in args.zones.split(","):
        spec = (cfg.get("zones") or {}).get(z)
        if spec is None:
            raise InputError(args.config[-1], f"zone {z!r} is not defined in {', '.join(args.config)}")
        zones[z] = spec["input"]
        models[z] = args.model or zone_model(work, z, str(spec.get("model") or inference["model"]))
    tta = [int(v) for v in args.tta.split(",")] if args.tta else [int(inference["tta"])]
    thr = _floats(args.threshold) if args.threshold else [float(towers["threshold"])]
    pthr = _floats(args.point_threshold) if args.point_threshold else [float(inference["threshold"])]
    mcp = _floats(args.min_core_prob) if args.min_core_prob else [float(towers["min_core_prob"])]
    gates = _floats(args.gate) if args.gate else [float(inference["gate"])]
    wires = _floats(args.min_wire_support) if args.min_wire_support else [float(towers["min_wire_support"])]
    rescues = _floats(args.rescue_threshold) if args.rescue_threshold else [float(towers["rescue_threshold"])]
    rows = sweep(
        zones,
        list(itertools.product(tta, thr, pthr, mcp, gates, wires, rescues)),
        work=work,
        model=models,
        inference=inference,
        towers=towers,
    )
    print("models: " + ", ".join(f"{z}: {Path(m).name}" for z, m in models.items()))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    print("\n".join(sweep_table(rows, list(zones))))
    return 0


def sweep_table(rows: Sequence[Mapping[str, Any]], zones: Sequence[str]) -> list[str]:
    """The lines ``towerpipe calibrate`` prints for :func:`sweep`'s rows: a header, then one line per
    candidate, each setting with the decimals it has (a gate of 0.005 is not 0.01)."""

    def f(v: Any) -> str:
        return "  -  " if v is None else f"{v:.3f}"

    lines = [
        "views  gate  threshold  points  min_core  wire  rescue | "
        + " | ".join(f"{z}: P / R / IoU" for z in zones)
        + " | mean F1 | mean IoU | found / true (of min_points or more) / false"
    ]
    for r in rows:
        cells = " | ".join(f"{f(r[z]['precision'])} / {f(r[z]['recall'])} / {r[z]['point_iou']:.4f}" for z in zones)
        lines.append(
            f"{r['tta']:5d}  {r['gate']:4g}  {r['threshold']:9g}  {r['point_threshold']:6g}  "
            f"{r['min_core_prob']:8g}  {r['min_wire_support']:4g}  {r['rescue_threshold']:6g} | {cells} | "
            f"{r['mean_f1']:.4f} | {r['mean_point_iou']:.4f} | {r['total_towers_tp']} / {r['total_true_towers']} "
            f"({r['total_towers_tp_min_points']} / {r['total_true_towers_min_points']}) / {r['total_towers_fp']}"
        )
    return lines


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="score views / thresholds on labelled calibration zones (after their run)")
    p.add_argument(
        "--config",
        nargs="+",
        default=["config/config.yaml", "config/models.yaml"],
        help="config files defining the zones and the other rules (later files win)",
    )
    p.add_argument("--zones", required=True, help="comma-separated calibration zones (never held-out ones)")
    p.add_argument("--tta", help="views to try, e.g. 1,2,4 (default: the config's)")
    p.add_argument("--threshold", help="towers.threshold values (default: the config's)")
    p.add_argument("--point-threshold", help="inference.threshold values (default: the config's)")
    p.add_argument("--min-core-prob", help="towers.min_core_prob values (default: the config's)")
    p.add_argument("--gate", help="inference.gate values (default: the config's); each predicts the zones again")
    p.add_argument("--min-wire-support", help="towers.min_wire_support values (default: the config's)")
    p.add_argument("--rescue-threshold", help="towers.rescue_threshold values (default: the config's)")
    p.add_argument("--model", help="model bundle directory (default: the config's inference.model)")
    p.add_argument("--workdir", help="workdir holding the zones' tiles (default: the config's)")
    p.add_argument("--json", help="also write the rows here")
    p.set_defaults(func=_cli)
