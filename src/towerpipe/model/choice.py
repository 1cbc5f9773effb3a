"""Which model a zone is run with, and why.

``inference.model`` (and a zone's own ``zones.<zone>.model``, which wins) is one of:

``auto`` (the default)
    Among the shipped models (:data:`towerpipe.model.cards.MODEL_RELEASES`) whose feature set
    needs only sensor attributes valid on *every* block of the zone
    (:mod:`towerpipe.preprocess.attributes`), the one that transfers best to real tower shapes: the
    highest ``transfer.score`` in its model card, measured by the leave-one-source-out
    real-shape benchmark (``docs/model.md``). Richer is not better: a column that only
    carried the training generator's signature does not help on real data. Scores closer
    than one benchmark tower (the card's ``transfer.resolution``: a difference the benchmark
    cannot tell from chance), or than the spread of a recipe's score between trainings
    (``transfer.spread``, where the card holds several ``runs``), are a tie, and the tie goes
    to the model that reads fewer sensor attributes, the one a degenerate column can mislead
    least.
a feature set (``full``, ``rgb``, ``geometry``, ``shape``)
    That shipped model.
a path
    A model directory (:func:`towerpipe.model.bundle.load_bundle`).

:func:`choose_model` returns the choice as a JSON-able record (``work/<zone>/model.json``);
every prediction file carries it, and the QA page and the GeoPackage name the model and
the reason. A block whose attributes an explicitly chosen model cannot use is listed in
``incompatible_blocks``: its inference fails with a message naming the config key to
change, and the zone's other blocks complete. This module does not import torch.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from towerpipe.errors import ConfigError, ModelError
from towerpipe.model.cards import MODEL_RELEASES, default_model_path, read_card
from towerpipe.preprocess.attributes import ATTRIBUTES, valid_set

AUTO = "auto"


def resolve_model(spec: str) -> Path:
    """The directory of a model named in the config: a shipped feature set's, or a path.

    ``auto`` is resolved per zone by :func:`choose_model`, never here.
    """
    if spec == AUTO:
        raise ConfigError(
            "`auto` is chosen per zone from its blocks' attributes (towerpipe.model.choice."
            "choose_model); name a feature set or a model directory here"
        )
    if spec in MODEL_RELEASES:
        return default_model_path(spec)
    return Path(spec)


def _card(path: Path) -> dict[str, Any] | None:
    try:
        return read_card(path)
    except ModelError:
        return None


def _transfer(card: Mapping[str, Any] | None) -> Mapping[str, Any]:
    """The card's ``transfer`` record (written by ``towerpipe realshape-stamp``), empty where absent."""
    t = (card or {}).get("transfer") or {}
    return t if isinstance(t, Mapping) else {}


def transfer_score(card: Mapping[str, Any] | None) -> float | None:
    """The card's real-shape transfer score (``transfer.score``), or ``None`` where not measured."""
    score = _transfer(card).get("score")
    return None if score is None else float(score)


def transfer_resolution(card: Mapping[str, Any] | None) -> float:
    """The smallest score difference the card's benchmark can tell: one tower
    (``transfer.resolution``), or the spread of the score between trainings of the recipe
    (``transfer.spread``) where that is larger; 0 where neither is recorded."""
    t = _transfer(card)
    return max(float(t.get("resolution") or 0.0), float(t.get("spread") or 0.0))


def best_transfer(usable: list[dict[str, Any]]) -> tuple[dict[str, Any], bool, float]:
    """The ``auto`` pick among usable candidates: ``(candidate, won a tie, the tie margin)``.

    Candidates whose score is within the benchmark's resolution of the best (the margin: the
    largest ``resolution`` among them, :func:`transfer_resolution`) tie; the tie goes to the fewest required sensor
    attributes, then to the order of :data:`~towerpipe.model.cards.MODEL_RELEASES`.
    Unmeasured models rank last.
    """
    from towerpipe.model.features import required_attributes

    order = {fs: i for i, fs in enumerate(MODEL_RELEASES)}
    measured = [c for c in usable if c["transfer"] is not None]
    if not measured:
        return min(usable, key=lambda c: order.get(c["feature_set"], len(order))), False, 0.0
    top = max(c["transfer"] for c in measured)
    margin = max(c.get("resolution") or 0.0 for c in measured)
    tied = [c for c in measured if top - c["transfer"] < margin or c["transfer"] == top]
    best = min(
        tied,
        key=lambda c: (
            len(required_attributes(c["feature_set"])),
            -c["transfer"],
            order.get(c["feature_set"], len(order)),
        ),
    )
    return best, len(tied) > 1, margin


def zone_attributes(block_attributes: Mapping[str, Mapping[str, Any] | None]) -> set[str]:
    """The attributes valid on every block (blocks whose split failed, ``None``, are left out)."""
    known = [valid_set(a) for a in block_attributes.values() if a is not None]
    return set.intersection(*known) if known else set()


def choose_model(
    spec: str, block_attributes: Mapping[str, Mapping[str, Any] | None], *, zone: str, key: str = "inference.model"
) -> dict[str, Any]:
    """The model of a zone and the reason (see the module docstring).

    Parameters
    ----------
    spec
        ``auto``, a shipped feature set or a model directory.
    block_attributes
        Block name -> its ``attributes`` record from the split (``None`` for a failed block).
    zone
        The zone (for messages).
    key
        The config key ``spec`` came from (``inference.model`` or ``zones.<zone>.model``).

    Returns
    -------
    dict
        ``mode`` (``auto`` / ``explicit``), ``key``, ``name``, ``version``, ``feature_set``,
        ``path``, ``reason``, ``valid_attributes``, ``candidates`` (auto) and
        ``incompatible_blocks`` (block -> the attributes it lacks).

    Raises
    ------
    ConfigError
        The model directory is missing or invalid, or no shipped model can be used.
    """
    from towerpipe.model.features import FEATURE_SETS, required_attributes

    valid = zone_attributes(block_attributes)
    lacking = sorted(set(ATTRIBUTES) - valid)
    why_not = f"valid on every block: {', '.join(sorted(valid)) or 'none'}" + (
        f"; not: {', '.join(lacking)}" if lacking else ""
    )
    if spec == AUTO:
        candidates = []
        for fs in MODEL_RELEASES:
            path = default_model_path(fs)
            card = _card(path)
            missing = [a for a in required_attributes(fs) if a not in valid]
            candidates.append(
                {
                    "feature_set": fs,
                    "name": None if card is None else card["name"],
                    "version": None if card is None else str(card["version"]),
                    "path": str(path),
                    "transfer": transfer_score(card),
                    "resolution": transfer_resolution(card),
                    "usable": card is not None and not missing,
                    "missing": missing,
                }
            )
        usable = [c for c in candidates if c["usable"]]
        if not usable:
            raise ConfigError(
                f"zone {zone!r}: no shipped model can be used ({why_not}; models in "
                f"{default_model_path('shape').parent}); set `{key}` to a model directory"
            )
        best, tie, margin = best_transfer(usable)
        scores = ", ".join(
            f"{c['feature_set']} {c['transfer']:.3f}"
            if c["transfer"] is not None
            else f"{c['feature_set']} (not measured)"
            for c in usable
        )
        model = f"{best['name']} v{best['version']}"
        if tie:
            why = f"{model} transfers as well as any usable model to real tower shapes and reads the fewest sensor attributes"
            detail = (
                f"scores within one benchmark tower or the spread between trainings, {margin:.3f}, tie; "
                f"benchmark score: {scores}"
            )
        else:
            why = f"{model} transfers best to real tower shapes among the usable models"
            detail = f"benchmark score: {scores}"
        reason = f"auto: {why_not}; {why} ({detail})"
        chosen = {
            "feature_set": best["feature_set"],
            "path": best["path"],
            "name": best["name"],
            "version": best["version"],
        }
        return {
            "mode": AUTO,
            "key": key,
            **chosen,
            "reason": reason,
            "valid_attributes": sorted(valid),
            "candidates": candidates,
            "incompatible_blocks": {},
        }
    path = resolve_model(spec)
    card = _card(path)
    if card is None:
        raise ConfigError(
            f"`{key}: {spec}`: {path} is not a towerpipe model directory (model_card.json); use "
            f"`auto`, one of {sorted(MODEL_RELEASES)} or a directory written by `towerpipe train`"
        )
    fs = card["feature_set"]
    if fs not in FEATURE_SETS:
        raise ConfigError(f"`{key}: {spec}`: unknown feature set {fs!r} in {path}")
    need = required_attributes(fs)
    bad = {b: [x for x in need if x not in valid_set(a)] for b, a in block_attributes.items() if a is not None}
    bad = {b: m for b, m in bad.items() if m}
    reason = f"set by `{key}: {spec}`"
    if bad:
        reason += f"; {len(bad)} block(s) lack what it needs ({', '.join(need)})"
    return {
        "mode": "explicit",
        "key": key,
        "feature_set": fs,
        "path": str(path),
        "name": card["name"],
        "version": str(card["version"]),
        "reason": reason,
        "valid_attributes": sorted(valid),
        "candidates": [],
        "incompatible_blocks": bad,
    }


def write_choice(
    spec: str,
    cache_dirs: Mapping[str, str | os.PathLike[str]],
    out_json: str | os.PathLike[str],
    *,
    zone: str,
    key: str,
) -> dict[str, Any]:
    """:func:`choose_model` from the zone's block caches, written to ``out_json`` (atomically)."""
    from towerpipe.io.atomic import write_text_atomic
    from towerpipe.io.blockcache import BlockCache

    attrs: dict[str, Mapping[str, Any] | None] = {}
    for block, d in cache_dirs.items():
        cache = BlockCache.open(d, allow_failed=True)
        attrs[block] = None if cache.failed else cache.meta.get("attributes")
    choice = choose_model(spec, attrs, zone=zone, key=key)
    write_text_atomic(out_json, json.dumps(choice, indent=1))
    return choice


def read_choice(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A choice written by :func:`write_choice`."""
    return json.loads(Path(path).read_text())


def incompatibility_error(choice: Mapping[str, Any], block: str) -> str | None:
    """The one-line error of a block the chosen model cannot use, else ``None``."""
    missing = (choice.get("incompatible_blocks") or {}).get(block)
    if not missing:
        return None
    return (
        f"block {block!r} has no valid {', '.join(missing)} but model {choice['name']} v{choice['version']} "
        f"(feature set {choice['feature_set']!r}, {choice['reason'].split(';')[0]}) needs it; set "
        f"`{choice['key']}: auto` to use a model these data support"
    )
