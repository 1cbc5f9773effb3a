"""The delivery's own point classes, for the QA pages: :func:`user_classes`, :func:`zone_user_classes`.

LAS 1.4 defines the classes up to 22 and leaves 64-255 to whoever classified the delivery
(:data:`towerpipe.classes.USER_DEFINED_MIN`). towerpipe cannot know what such a class holds, so
its points are points of the scene: they reach the model and the tower search unless
``preprocess.extra_noise_classes`` lists the class. Most are objects of the scene (a producer's
own subclasses), but not all: LiDAR HD's class 65, its artefacts (the README of ``../shared``),
stands on the real tiles of ``../shared`` as curtains of points from the ground to 84 m
above it, and such a curtain in a tower's window lowers what the segmenter paints on the tower
(docs/model.md, "The artefacts of a real tile left in the model's input"). The block's QA page
lists each such class, its points and how high above the ground they reach, and the zone's index
sums them over its blocks, so that an operator can tell which of them to list as noise.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from towerpipe.classes import USER_DEFINED_MIN

__all__ = ["user_class_rows", "user_classes", "zone_user_classes"]


def user_classes(cls: np.ndarray, hag: np.ndarray | None) -> dict[int, dict[str, float | int | None]]:
    """Each class of the delivery's own (:data:`~towerpipe.classes.USER_DEFINED_MIN` or above) among
    the block's points.

    Parameters
    ----------
    cls
        The points' classes as the QA page reads them: the classified block, whose points of
        the delivery's noise classes read 7 and whose reported towers' points read 15 (a
        class's points in a tower are counted as the tower's).
    hag
        Their heights above ground, or ``None`` when unknown.

    Returns
    -------
    dict
        Class -> ``points`` and ``hag_max`` (the highest of them above the ground, m; ``None``
        when ``hag`` is), in class order; empty when the block has none.
    """
    cls = np.asarray(cls)
    hag = np.asarray(hag, np.float64) if hag is not None else None  # once, not once a class
    counts = np.bincount(cls.astype(np.int64), minlength=256)
    out: dict[int, dict[str, float | int | None]] = {}
    for c in np.flatnonzero(counts[USER_DEFINED_MIN:]) + USER_DEFINED_MIN:
        h = hag[cls == c] if hag is not None else np.empty(0)
        top = float(np.nanmax(h)) if np.isfinite(h).any() else None  # unknown: no height, or none known
        out[int(c)] = {"points": int(counts[c]), "hag_max": top}
    return out


def user_class_rows(user: dict[int, dict[str, float | int | None]]) -> list[tuple[str, int]]:
    """The rows of the QA page's table of points for :func:`user_classes`' answer."""
    return [
        (
            f"input: class {c}, the delivery's own, taken as any point"
            + (f" (up to {u['hag_max']:.1f} m above the ground)" if u["hag_max"] is not None else ""),
            int(u["points"] or 0),
        )
        for c, u in user.items()
    ]


def zone_user_classes(block_docs: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The delivery's own classes over a zone, from its blocks' QA JSONs (their ``user_classes``).

    Returns
    -------
    list of dict
        One per class, in class order: ``class``, ``blocks`` (holding it), ``points`` and
        ``hag_max`` (the highest over the blocks that know it, else ``None``).
    """
    out: dict[int, dict[str, Any]] = {}
    for doc in block_docs:
        for c, u in (doc.get("user_classes") or {}).items():
            row = out.setdefault(int(c), {"class": int(c), "blocks": 0, "points": 0, "hag_max": None})
            row["blocks"] += 1
            row["points"] += int(u.get("points") or 0)
            top = u.get("hag_max")
            if top is not None and (row["hag_max"] is None or top > row["hag_max"]):
                row["hag_max"] = float(top)
    return [out[c] for c in sorted(out)]
