"""The real-shape benchmark: do the models find real towers of a family they never saw?

No public labelled airborne data set with towers is in reach, so the models train on
generated zones with real tower shapes mixed in, and models that learn the generator
rather than towers score well on generated zones. This benchmark measures transfer
instead, leaving one *source* out:

* the real tower families of ``../shared/data/real/towers`` (:data:`FAMILIES`: TS40K
  lattice towers, UAV-scanned lattice towers, airborne utility structures) are each set
  into the real IGN RGB+NIR tile — a background no training zone uses — on parallel lines
  with conductors, thinned to 4-15 pts/m² (zones ``realshape_<family>_<variant>`` of
  ``config/models.yaml``, :mod:`towerpipe.synth.background`);
* each zone exists intact and degraded (:data:`VARIANTS`): intensity, returns, scan angle
  and GPS time all 0; NIR all 0; no colour at all; no wire class (conductors class 1);
* each recipe (a feature set of the shipped family) is trained once per family *without*
  that family (``<model>-without-<family>``) and judged on that family's zones where its
  features are usable (their attributes valid on the zone), with the configured inference
  and tower rules: gate recall, tower recall and precision, point IoU of class 15. As in the
  paper, a tower needs ``towers.min_points`` (20) points to count: a thinner one (a pole at 4
  pts/m²) is neither a missed tower nor, when found, a false one.

A recipe's **transfer score** is its mean tower F1 over the held-out families on the
intact zones (all recipes are usable there), and its **resolution** what one tower weighs
in it (:func:`score_resolution`); ``inference.model: auto`` (:mod:`towerpipe.model.choice`)
picks the usable shipped model with the highest score, scores closer than the resolution
counting as a tie that the model reading fewer sensor attributes wins; both are recorded
in each shipped card by :func:`stamp_cards`. Two trainings of one recipe can differ by more
than a tower (the leave-one-source-out models are trained again each run): stamped with
``--add``, a card keeps every run, its score is their mean and the spread of their scores
widens the tie. The ``auto`` rows of the report
are what a user gets: per family and variant, the recipe ``auto`` would choose.

``snakemake --cores 2 results/benchmark/realshape/`` trains what is missing and writes
``report.md`` and ``scores.json``; ``towerpipe realshape-stamp`` copies the scores into the
shipped cards (``--add``: as one more training of the recipes already stamped).
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.synth.delivery import VARIANTS
from towerpipe.synth.real import FAMILIES

__all__ = ["FAMILIES", "VARIANTS", "evaluate_model", "run_benchmark", "stamp_cards", "zone_name"]

#: Bars of the benchmark (per family held out and variant): tower recall and precision.
BARS = {"recall": 0.9, "precision": 0.9}


def zone_name(family: str, variant: str) -> str:
    """The config zone of a family and variant: ``realshape_<family>_<variant>``."""
    return f"realshape_{family}_{variant}"


def zone_valid_attributes(work: str | os.PathLike[str], zone: str) -> set[str]:
    """The sensor attributes valid on every tile of a preprocessed zone."""
    from towerpipe.evaluation.predcache import zone_tiles
    from towerpipe.io.columns import read_meta
    from towerpipe.model.features import valid_attributes

    sets = [valid_attributes(read_meta(p)) for p in zone_tiles(work, zone)]
    return set.intersection(*sets) if sets else set()


def evaluate_model(
    model: str | os.PathLike[str],
    zone: str,
    input_dir: str | os.PathLike[str],
    *,
    work: str | os.PathLike[str],
    inference: Mapping[str, Any],
    towers: Mapping[str, Any],
) -> dict[str, Any]:
    """A model's figures on one preprocessed labelled zone (:func:`towerpipe.evaluation.calibrate.score_zone`).

    Predictions are cached per model weights, inference settings and shape-gate verifier
    (``towers["verifier"]``: :func:`towerpipe.evaluation.predcache.zone_predictions`).
    """

    from towerpipe.config import InferenceConfig
    from towerpipe.evaluation.calibrate import score_zone, zone_survey
    from towerpipe.evaluation.predcache import zone_predictions, zone_tiles
    from towerpipe.evaluation.truth import zone_labels
    from towerpipe.io.predictions import load_pred
    from towerpipe.synth.truth import TRUTH_GPKG

    settings = InferenceConfig.from_config({"inference": inference})
    preds = [load_pred(p) for p in zone_predictions(work, zone, model, settings, towers["verifier"])]
    truth, labels = zone_labels(input_dir, Path(input_dir) / TRUTH_GPKG)
    return score_zone(
        preds,
        [str(p) for p in zone_tiles(work, zone)],
        truth,
        labels,
        threshold=float(towers["threshold"]),
        point_threshold=float(inference["threshold"]),
        min_core_prob=float(towers["min_core_prob"]),
        towers=towers,
        survey=zone_survey(work, zone),
        zone=zone,
        min_truth_points=int(towers["min_points"]),
    )


def _f1(row: Mapping[str, Any]) -> float:
    return float(row["f1"]) if row.get("f1") is not None else 0.0


def score_resolution(rows: list[Mapping[str, Any]]) -> float | None:
    """What one tower weighs in a transfer score: ``1 / (n x families)`` for the family with most towers.

    The score is a mean over the held-out families of their tower F1; one tower more or
    less found in a family of ``n`` towers moves that family's recall by ``1 / n``. Two
    scores closer than the smallest such step differ by less than one tower: the benchmark
    cannot tell them apart (:func:`towerpipe.model.choice.best_transfer`).
    """
    sizes = [int(r.get("towers_tp") or 0) + int(r.get("towers_fn") or 0) for r in rows]
    sizes = [n for n in sizes if n > 0]
    return 1.0 / (max(sizes) * len(rows)) if sizes else None


def run_benchmark(
    loso: Mapping[str, Mapping[str, str | os.PathLike[str]]],
    zones: Mapping[str, str | os.PathLike[str]],
    *,
    work: str | os.PathLike[str],
    inference: Mapping[str, Any],
    towers: Mapping[str, Any],
    out_dir: str | os.PathLike[str],
    reference: Mapping[str, str | os.PathLike[str]] | None = None,
    verifiers: Mapping[str, str | os.PathLike[str]] | None = None,
) -> dict[str, Any]:
    """Run the benchmark and write ``report.md`` and ``scores.json`` into ``out_dir``.

    Parameters
    ----------
    loso
        Recipe (feature set) -> family -> the model trained without that family.
    zones
        Zone name (:func:`zone_name`) -> input directory (labelled blocks + truth); the
        zones must have been preprocessed (their tiles under ``work``).
    work
        The workdir.
    inference, towers
        The config's sections (thresholds and rules as a user runs them).
    out_dir
        Output directory.
    reference
        Optional label -> model run on every zone too (e.g. the shipped models, which
        saw every family: a reference, not a transfer figure).
    verifiers
        Family -> the shape verifier trained without it (``towers.verifier`` on that
        family's zones); default: ``towers.verifier`` everywhere.

    Returns
    -------
    dict
        ``rows`` (one per recipe, family and variant; ``usable`` False where the recipe's
        attributes are not valid on the zone), ``auto`` rows, ``transfer`` per recipe and
        the ``bars`` check.
    """
    from towerpipe.model.cards import read_card
    from towerpipe.model.choice import best_transfer
    from towerpipe.model.features import required_attributes

    valid = {z: zone_valid_attributes(work, z) for z in zones}
    rows: list[dict[str, Any]] = []
    for recipe, per_family in loso.items():
        for family, model in per_family.items():
            card = read_card(model)
            need = required_attributes(card["feature_set"])
            for variant in VARIANTS:
                zone = zone_name(family, variant)
                if zone not in zones:
                    continue
                missing = sorted(set(need) - valid[zone])
                row: dict[str, Any] = {
                    "recipe": recipe,
                    "feature_set": card["feature_set"],
                    "family": family,
                    "variant": variant,
                    "zone": zone,
                    "model": card["name"],
                    "usable": not missing,
                    "missing": missing,
                }
                if not missing:
                    own = (verifiers or {}).get(family)
                    rules = {**towers, **({"verifier": str(own)} if own else {})}
                    row.update(evaluate_model(model, zone, zones[zone], work=work, inference=inference, towers=rules))
                rows.append(row)
    transfer = {}
    for recipe in loso:
        intact = [r for r in rows if r["recipe"] == recipe and r["variant"] == "intact" and r["usable"]]
        transfer[recipe] = {
            "score": float(np.mean([_f1(r) for r in intact])) if intact else None,
            "point_iou": float(np.nanmean([r["point_iou"] for r in intact])) if intact else None,
            "families": sorted({r["family"] for r in intact}),
            "resolution": score_resolution(intact),
        }
    auto = []
    for family in sorted({r["family"] for r in rows}):
        for variant in VARIANTS:
            usable = [r for r in rows if r["family"] == family and r["variant"] == variant and r["usable"]]
            if usable:
                best = best_transfer(
                    [
                        {
                            "feature_set": r["feature_set"],
                            "transfer": transfer[r["recipe"]]["score"],
                            "resolution": transfer[r["recipe"]]["resolution"],
                            "row": r,
                        }
                        for r in usable
                    ]
                )[0]["row"]
                ok = all((best.get(k) or 0.0) >= v for k, v in BARS.items())
                auto.append({**best, "meets_bars": ok})
    refs = []
    for label, model in (reference or {}).items():
        card = read_card(model)
        need = required_attributes(card["feature_set"])
        for zone in zones:
            if set(need) <= valid[zone]:
                refs.append(
                    {
                        "reference": label,
                        "model": card["name"],
                        "zone": zone,
                        **evaluate_model(model, zone, zones[zone], work=work, inference=inference, towers=towers),
                    }
                )
    result = {
        "rows": rows,
        "auto": auto,
        "transfer": transfer,
        "reference": refs,
        "bars": BARS,
        "inference": dict(inference),
        "towers": dict(towers),
        "verifiers": {k: str(v) for k, v in (verifiers or {}).items()},
        "all_bars_met": bool(auto) and all(a["meets_bars"] for a in auto),
    }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scores.json").write_text(json.dumps(result, indent=1, default=str))
    (out / "report.md").write_text(report_markdown(result))
    return result


def _fmt(v: Any, nd: int = 2) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    return f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def report_markdown(result: Mapping[str, Any]) -> str:
    """The benchmark's tables as Markdown."""
    lines = [
        "# Real-shape benchmark (leave one source out)",
        "",
        "Each real tower family on the IGN RGB+NIR tile, judged with models trained without it. "
        "Gate recall: true towers reached by a window passing the gate. Towers: recall / precision "
        "(true towers); point IoU of class 15.",
        "",
        "## What `inference.model: auto` gives",
        "",
        "| family held out | variant | model chosen | gate recall | tower recall | precision | point IoU "
        "| true towers | false towers | bars (R, P >= 0.9) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for a in result["auto"]:
        lines.append(
            f"| {a['family']} | {a['variant']} | {a['feature_set']} | {_fmt(a['gate_recall'])} | "
            f"{_fmt(a['recall'])} | {_fmt(a['precision'])} | {_fmt(a['point_iou'], 3)} | "
            f"{a['true_towers']} | {a['towers_fp']} | {'met' if a['meets_bars'] else '**not met**'} |"
        )
    lines += [
        "",
        "## Transfer score per recipe (mean tower F1 over the held-out families, intact zones)",
        "",
        "| recipe | score | mean point IoU |",
        "|---|---|---|",
    ]
    for recipe, t in result["transfer"].items():
        lines.append(f"| {recipe} | {_fmt(t['score'], 3)} | {_fmt(t['point_iou'], 3)} |")
    lines += [
        "",
        "## Every recipe, family and variant",
        "",
        "| recipe | family held out | variant | gate recall | tower recall | precision | point IoU | false towers |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        if not r["usable"]:
            lines.append(
                f"| {r['recipe']} | {r['family']} | {r['variant']} | not usable: no valid "
                f"{', '.join(r['missing'])} | | | | |"
            )
            continue
        lines.append(
            f"| {r['recipe']} | {r['family']} | {r['variant']} | {_fmt(r['gate_recall'])} | "
            f"{_fmt(r['recall'])} | {_fmt(r['precision'])} | {_fmt(r['point_iou'], 3)} | {r['towers_fp']} |"
        )
    if result["reference"]:
        lines += [
            "",
            "## Reference: models that saw every family",
            "",
            "| model | zone | tower recall | precision | point IoU |",
            "|---|---|---|---|---|",
        ]
        for r in result["reference"]:
            lines.append(
                f"| {r['model']} | {r['zone']} | {_fmt(r['recall'])} | {_fmt(r['precision'])} | "
                f"{_fmt(r['point_iou'], 3)} |"
            )
    return "\n".join(lines) + "\n"


def stamp_cards(
    scores_json: str | os.PathLike[str], models: Mapping[str, str | os.PathLike[str]], *, add: bool = False
) -> list[Path]:
    """Write each recipe's transfer figures into its shipped model's card (``transfer``).

    Parameters
    ----------
    scores_json
        The benchmark's ``scores.json``.
    models
        Recipe (feature set) -> shipped model directory.
    add
        This run is another training of the same recipes: it joins the card's earlier ``runs``
        (a card stamped before runs were kept counts as one), ``score`` and ``point_iou`` become
        their means and ``spread`` the range of their scores, which ``inference.model: auto``
        reads as a tie margin (:func:`towerpipe.model.choice.transfer_resolution`); the other
        figures are this run's. Without it, this run replaces the card's figures.
    """
    from towerpipe.model.cards import read_card, write_card

    result = json.loads(Path(scores_json).read_text())
    done = []
    for recipe, model in models.items():
        t = result["transfer"].get(recipe)
        if t is None:
            continue
        card = read_card(model)
        run = {
            "score": t["score"],
            "point_iou": t["point_iou"],
            "per_family": [
                {k: r.get(k) for k in ("family", "variant", "gate_recall", "recall", "precision", "point_iou")}
                for r in result["rows"]
                if r["recipe"] == recipe and r["usable"]
            ],
        }
        runs = _earlier_runs(card.get("transfer") or {}) if add else []
        runs.append(run)
        scores = [r["score"] for r in runs]
        card["transfer"] = {
            "benchmark": "real-shape, leave one source out (towerpipe.evaluation.realshape)",
            "score": float(np.mean(scores)),
            "resolution": t.get("resolution"),
            "spread": float(max(scores) - min(scores)),
            "point_iou": float(np.mean([r["point_iou"] for r in runs])),
            "families": t["families"],
            "per_family": run["per_family"],
            "runs": runs,
        }
        write_card(model, card)
        done.append(Path(model))
    return done


def _earlier_runs(transfer: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The runs of a card's transfer record; one stamped before runs were kept is one run."""
    if transfer.get("runs"):
        return list(transfer["runs"])
    if transfer.get("score") is None:
        return []
    return [{k: transfer.get(k) for k in ("score", "point_iou", "per_family")}]


def _stamp(args: argparse.Namespace) -> int:
    from towerpipe.model.cards import CARD_FILE, MODEL_RELEASES, default_model_path

    models = {fs: default_model_path(fs) for fs in MODEL_RELEASES}
    for p in stamp_cards(args.scores, models, add=args.add):
        print(f"stamped {p / CARD_FILE}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``towerpipe realshape-stamp`` to the command line."""
    p = sub.add_parser(
        "realshape-stamp",
        help="copy the real-shape benchmark's transfer scores into the shipped "
        "model cards (what inference.model: auto ranks by)",
    )
    p.add_argument("--scores", default="results/benchmark/realshape/scores.json")
    p.add_argument(
        "--add",
        action="store_true",
        help="another training of the same recipes: keep the cards' earlier runs, stamp their mean "
        "score and its spread (a tie margin of inference.model: auto)",
    )
    p.set_defaults(func=_stamp)
