"""Why a true tower was missed: each labelled tower of a zone the pipeline has run, and the
stage that lost it (``towerpipe trace``).

The tower rules are run again on the zone's own predictions and tiles (those of its last
run under ``<workdir>/<zone>/``, or with ``--cached`` those of today's inference that
:mod:`towerpipe.evaluation.predcache` keeps for the calibration), as the towers jobs and
:func:`towerpipe.evaluation.calibrate.score_zone` run them, with a ``trace``
(:func:`towerpipe.towers.extract.extract_towers`) that records what decided every cluster. A true tower is then:

- ``found``: a reported tower matches it (within 5 m, :func:`towerpipe.towers.matching.match_towers`);
  the points that tower reports are counted, and those of them the input does not label as
  tower (crowns or ground painted with it: what its point IoU loses besides the points it misses);
- ``not segmented``: no point within 1 m of its footprint was segmented; the windows' gates
  (:func:`towerpipe.inference.windows.window_gates`, recorded by each inference job) then say why:
  ``no window`` (no window centred within 1 m of its footprint: no height peak on it),
  ``shape gate`` (every such window's peak object scored under ``inference.shape_gate``; the
  value is the best score), ``classifier gate`` (every one the shape gate let through scored
  under ``inference.gate``; the value is the best probability), ``unsure gate`` (every one the
  classifier passed it was unsure of, under ``inference.gate_sure``, and its peak object scored
  under ``inference.unsure_shape``; the value is the best probability); it stays ``not segmented``
  when a window over it passed both gates (a secondary peak near a segmented one) or its
  predictions hold no such record (written before 0.8.13);
- ``faint``: segmented, but no point reaches the probability that clusters
  (``towers.threshold``, or ``towers.rescue_threshold`` with the rescue);
- ``no cluster``: its points made no cluster of ``towers.min_points`` points and
  ``towers.min_height`` m;
- else the rule that dropped the cluster holding most of its points (:data:`RULE_NAMES`),
  with what that rule measured; ``merged`` when that cluster was reported as one tower with a
  true tower beside it, which it matched (two lines side by side: the value is the distance
  between the two, m); ``accepted`` when it was reported and lies more than 5 m from it.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.inference.windows import classifier_pass

__all__ = ["GATE_STAGES", "MERGED", "RULE_NAMES", "STAGE_NAMES", "trace_zone", "trace_table"]

#: What each rule of a trace means to a reader (:data:`towerpipe.towers.extract.TRACE_RULES`).
RULE_NAMES = {
    "core": "no confident core (towers.min_core_prob, towers.tall_core_prob)",
    "floating": "floating above the ground (towers.max_base_ratio)",
    "stands": "nothing in it stands, a piece of conductor (towers.min_stand)",
    "line": "it lies along the conductors found around it (towers.max_line_share)",
    "points": "too few points reported (towers.min_points)",
    "jib": "a narrow arm reaching far on one side, a crane's jib (towers.max_arm_reach)",
    "context": "no tile around it for the rescue's shape check",
    "shape": "shape check (towers.min_shape_score)",
    "bare": "without the conductors through it, a crown (towers.min_bare_score)",
    "under": "a line's conductors over it and none at or below its top, a crown (towers.under_line)",
    "canopy": "few conductors near it and hardly over the wood around it, a crown (towers.canopy)",
    "wires": "conductor support (towers.min_wire_support), the conductors near it not keeping it (towers.min_near_balance)",
    "sides": "every conductor on one side of it (towers.min_conductor_balance)",
    "near": "its ring outside the data, the conductors near it on one side or passing by (towers.min_near_balance)",
    "accepted": "reported, more than 5 m away",
}
#: The stage of a tower reported as one with a true tower beside it (:func:`trace_zone`).
MERGED = "merged"
#: What each gate stage of a tower never segmented means to a reader.
GATE_STAGES = {
    "no window": "not segmented: no window on it (no height peak)",
    "shape gate": "not segmented: shape gate (inference.shape_gate)",
    "classifier gate": "not segmented: classifier gate (inference.gate)",
    "unsure gate": "not segmented: classifier unsure and shape low (inference.gate_sure, inference.unsure_shape)",
}
#: Every stage of a missed tower, as a reader reads it.
STAGE_NAMES = {
    **RULE_NAMES,
    **GATE_STAGES,
    MERGED: "reported as one tower with the true tower beside it (value: the distance between them, m)",
}


def trace_zone(
    work: str | os.PathLike[str],
    zone: str,
    input_dir: str | os.PathLike[str],
    *,
    inference: Mapping[str, Any],
    towers: Mapping[str, Any],
    truth_file: str | os.PathLike[str] | None = None,
    predictions: Sequence[str | os.PathLike[str]] | None = None,
) -> list[dict[str, Any]]:
    """One row per true tower of a zone: found, or the stage that lost it.

    Parameters
    ----------
    work
        The workdir; the zone's predictions, tiles and plan are read under ``<work>/<zone>/``.
    zone
        The zone's name.
    input_dir
        The zone's labelled input (``towers_truth.gpkg`` unless ``truth_file``).
    inference, towers
        The config's sections, as the zone was run (``inference.threshold``, the tower rules).
    truth_file
        True tower footprints (layer ``towers``).
    predictions
        The prediction files to trace (default: the zone's last run, ``<work>/<zone>/pred/*/*.npz``;
        e.g. :func:`towerpipe.evaluation.predcache.zone_predictions` for another model or setting).

    Returns
    -------
    list of dict
        ``tower_id``, ``design``, ``height_m``, ``n_points`` (of the truth), ``stage`` (``found``,
        ``no window``, ``shape gate``, ``classifier gate``, ``not segmented``, ``faint``, ``no
        cluster`` or a rule of :data:`RULE_NAMES`), ``value``
        (what that stage measured: the highest probability, the shape score, ...),
        ``cluster_points`` (of the deciding cluster), ``max_prob`` (the highest
        single-view probability segmented within 1 m of it) and, for a found tower,
        ``reported_points`` (the points its reported tower classifies as tower) and
        ``reported_other`` (those of them not labelled tower in the input). True towers under
        ``towers.min_points`` points are left out, as the scores leave them out.
    """
    import shapely

    from towerpipe.config import TowersConfig
    from towerpipe.evaluation.calibrate import NEAR_TOWER_M, zone_survey, zone_towers
    from towerpipe.evaluation.predcache import zone_tiles
    from towerpipe.evaluation.truth import zone_labels
    from towerpipe.io import workdir
    from towerpipe.io.predictions import load_pred
    from towerpipe.towers.matching import match_towers

    pred_files = list(predictions) if predictions is not None else workdir.zone_files(work, zone, workdir.PRED)
    if not pred_files:
        from towerpipe.errors import InputError

        raise InputError(
            Path(work, zone, "pred"),
            f"no predictions of zone {zone!r}; run `snakemake --cores 2 results/{zone}/` first",
        )
    truth, labels = zone_labels(input_dir, truth_file)
    rules = TowersConfig.from_config({"towers": dict(towers)})
    preds = [load_pred(p) for p in pred_files]
    trace: list[dict[str, Any]] = []
    found = zone_towers(
        preds,
        zone_tiles(work, zone),
        towers,
        point_threshold=float(inference["threshold"]),
        survey=zone_survey(work, zone),
        zone=zone,
        crs=truth.crs,
        trace=trace,
    )
    matched = {str(m["truth"]): m["pred"] for m in match_towers(found.towers, truth, max_dist=5.0)["matches"]}
    x = np.concatenate([np.asarray(p.arrays["x"], np.float64) for p in preds])
    y = np.concatenate([np.asarray(p.arrays["y"], np.float64) for p in preds])
    prob = np.concatenate([np.asarray(p.arrays["prob_single"], np.float64) for p in preds])
    floor = min(float(rules.threshold), float(rules.rescue_threshold) or float(rules.threshold))
    gates = _window_gates(preds, inference)
    rows = []
    for _, t in truth.iterrows():
        n_true = int(t["n_points"]) if "n_points" in truth.columns else -1
        if 0 <= n_true < int(rules.min_points):
            continue
        near = shapely.buffer(t.geometry, NEAR_TOWER_M)  # as gate_recall looks
        here = shapely.contains_xy(near, x, y)
        row = {
            "tower_id": str(t["tower_id"]),
            "design": str(t.get("design", "")),
            "height_m": float(t["height"]) if "height" in truth.columns else float("nan"),
            "n_points": n_true,
            "max_prob": float(prob[here].max()) if here.any() else 0.0,
            "stage": "found",
            "value": float("nan"),
            "cluster_points": 0,
            "reported_points": 0,
            "reported_other": 0,
        }
        if str(t["tower_id"]) in matched:
            row.update(_reported(found.members, matched[str(t["tower_id"])], labels))
        elif not here.any():
            stage, value = _gate_stage(near, gates)
            row.update(stage=stage, value=value)
        elif row["max_prob"] < floor:
            row.update(stage="faint", value=row["max_prob"])
        else:
            # the cluster holding most of its points decides (a split's parts and the rescue's
            # clusters included); the last such decision wins a tie: it is the later judgement
            best, best_n = None, 0
            for entry in trace:
                n = int(shapely.contains_xy(near, entry["x"], entry["y"]).sum())
                if n and n >= best_n:
                    best, best_n = entry, n
            if best is None:
                row["stage"] = "no cluster"
            else:
                row.update(stage=best["rule"], value=best["value"], cluster_points=len(best["x"]))
                if best["rule"] == "accepted" and np.isfinite(beside := _merged_with(best, t.geometry, truth, matched)):
                    row.update(stage=MERGED, value=beside)
        rows.append(row)
    return rows


def _merged_with(entry: Mapping[str, Any], footprint: Any, truth: Any, matched: Mapping[str, Any]) -> float:
    """The distance (m) from a true tower's ``footprint`` to the nearest other true tower that a
    reported tower matched and whose footprint centroid lies among the points of ``entry`` (the
    accepted cluster holding the tower: reported as one with it); ``nan`` when there is none."""
    import shapely

    from towerpipe.towers.hull import plan_hull

    hull = shapely.buffer(plan_hull(np.c_[entry["x"], entry["y"]]), 1.0)
    others = truth[truth["tower_id"].astype(str).isin(list(matched)) & ~truth.geometry.geom_equals(footprint)]
    c = others.geometry.centroid
    d = c[shapely.contains_xy(hull, c.x.to_numpy(), c.y.to_numpy())].distance(footprint.centroid)
    return float(d.min()) if len(d) else float("nan")


def _reported(members: Mapping[Any, Any], tower_id: Any, labels: Mapping[str, np.ndarray]) -> dict[str, int]:
    """The points a reported tower classifies as tower, and those of them the input does not label 15."""
    key = int(tower_id) if str(tower_id).isdigit() else tower_id  # the members' keys are the ids as numbers
    blocks, idx = members.get(key, ((), ()))
    blocks, idx = np.asarray(blocks).astype(str), np.asarray(idx, np.int64)
    other = sum(
        int(np.isin(idx[blocks == b], labels.get(str(b), np.empty(0, np.int64)), invert=True).sum())
        for b in np.unique(blocks)
    )
    return {"reported_points": int(idx.size), "reported_other": other}


def _window_gates(preds: Sequence[Any], inference: Mapping[str, Any]) -> dict[str, Any] | None:
    """The windows' gate records of every tile, one column each (``None`` if a prediction file
    has none: written before they were recorded), and the classifier's gate as the tiles ran it."""
    recs = [p.meta.get("window_gates") for p in preds]
    if not recs or any(r is None for r in recs):
        return None

    def cat(key: str) -> np.ndarray:
        return np.array([np.nan if v is None else v for r in recs for v in r[key]], dtype=np.float64)

    return {
        "x": cat("x"),
        "y": cat("y"),
        "shape": cat("shape"),
        "prob": cat("prob"),
        "gate": float(preds[0].meta.get("gate_threshold", inference["gate"])),
        # the unsure windows' condition as the tiles ran it (none before it was recorded)
        "gate_sure": float(preds[0].meta.get("gate_sure") or 0.0),
        "unsure_shape": float(preds[0].meta.get("unsure_shape") or 0.0),
    }


def _gate_stage(near: Any, gates: Mapping[str, Any] | None) -> tuple[str, float]:
    """Why no window segmented a tower whose footprint (buffered) is ``near``: the gate that
    refused every window centred on it, and the best score that gate saw."""
    import shapely

    if gates is None:
        return "not segmented", float("nan")
    on = shapely.contains_xy(near, gates["x"], gates["y"])
    if not on.any():
        return "no window", float("nan")
    shape, prob = gates["shape"][on], gates["prob"][on]
    if np.isfinite(prob).any():
        best = float(np.nanmax(prob))
        if best < gates["gate"]:
            return "classifier gate", best
        passed = classifier_pass(
            np.nan_to_num(prob, nan=-1.0),
            shape,
            gates["gate"],
            gates.get("gate_sure", 0.0),
            gates.get("unsure_shape", 0.0),
        )
        # a window over it passed every gate and was still not segmented (a secondary peak near a
        # segmented one): the gates did not lose it
        return ("not segmented" if passed.any() else "unsure gate"), best
    return "shape gate", float(np.nanmax(shape)) if np.isfinite(shape).any() else float("nan")


def trace_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """The rows of :func:`trace_zone` as a Markdown table, the missed towers first."""

    def key(r: Mapping[str, Any]) -> tuple[bool, int, str]:
        tid = str(r["tower_id"])
        return r["stage"] == "found", int(tid) if tid.isdigit() else 0, tid

    order = sorted(rows, key=key)
    lines = [
        "| tower | design | height (m) | true points | highest probability | stage | value | cluster points "
        "| reported points | of them not tower |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in order:
        stage = STAGE_NAMES.get(r["stage"], r["stage"])
        value = "" if not np.isfinite(r["value"]) else f"{r['value']:.3f}"
        lines.append(
            f"| {r['tower_id']} | {r['design']} | {r['height_m']:.1f} | {r['n_points']} | {r['max_prob']:.2f} | "
            f"{stage} | {value} | {r['cluster_points'] or ''} | {r.get('reported_points') or ''} | "
            f"{r.get('reported_other', '') if r.get('reported_points') else ''} |"
        )
    missed = sum(r["stage"] != "found" for r in rows)
    lines.append("")
    lines.append(f"{len(rows) - missed} of {len(rows)} true towers found.")
    return "\n".join(lines)


def _cli(args: argparse.Namespace) -> int:
    from towerpipe.config import effective_config
    from towerpipe.errors import InputError

    cfg = effective_config(args.config)
    spec = (cfg.get("zones") or {}).get(args.zone)
    if spec is None:
        raise InputError(args.config[-1] if args.config else "config", f"zone {args.zone!r} is not defined")
    work = args.workdir or cfg["workdir"]
    preds = None
    if args.cached:  # the current inference's predictions, as `towerpipe calibrate` scores them
        from towerpipe.config import InferenceConfig
        from towerpipe.evaluation.calibrate import zone_model
        from towerpipe.evaluation.predcache import zone_predictions

        model = args.model or zone_model(work, args.zone, str(spec.get("model") or cfg["inference"]["model"]))
        settings = InferenceConfig.from_config(cfg)
        preds = zone_predictions(work, args.zone, model, settings, cfg["towers"]["verifier"])
    rows = trace_zone(
        work,
        args.zone,
        spec["input"],
        inference=cfg["inference"],
        towers=cfg["towers"],
        truth_file=args.truth,
        predictions=preds,
    )
    print(trace_table(rows))
    if args.json:
        plain = [{k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in r.items()} for r in rows]
        Path(args.json).write_text(json.dumps(plain, indent=1))  # NULL, not NaN: strict JSON
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("trace", help="why each true tower of a labelled zone was missed (after its run)")
    p.add_argument("--zone", required=True, help="a labelled zone of the config, run with `snakemake`")
    p.add_argument(
        "--config",
        nargs="*",
        default=[],
        help="config files over config/config.yaml and config/models.yaml, as the zone was run",
    )
    p.add_argument("--workdir", help="the workdir (default: the config's)")
    p.add_argument(
        "--truth",
        help="true tower footprints (default: <input>/towers_truth.gpkg, else the towers its blocks label 15)",
    )
    p.add_argument("--json", help="write the rows here")
    p.add_argument(
        "--cached",
        action="store_true",
        help="trace the predictions of today's inference code and the config's inference settings, "
        "as `towerpipe calibrate` scores them (cached under <workdir>/<zone>/calibrate/, made if "
        "missing), instead of the zone's last run",
    )
    p.add_argument("--model", help="with --cached: the model bundle (default: the zone's choice, as it was run)")
    p.set_defaults(func=_cli)
