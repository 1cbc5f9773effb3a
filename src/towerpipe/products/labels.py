"""What the merge writes into each point of a block: its tower probability, its tower id and its class.

:func:`block_probabilities` reads a block's prediction files (the highest probability of the
segmented windows that saw a point); :func:`relabel` decides the classes (15 on the points of the
reported towers, an input 15 that is not one back to 1, a withheld point's class kept);
:func:`block_labels` puts them together for :func:`towerpipe.products.merge.merge_block`, and the
QA step classifies the block's cached points with it instead of decoding the written LAZ.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe import classes
from towerpipe.errors import InputError
from towerpipe.io.predictions import load_pred

__all__ = ["BlockLabels", "block_labels", "block_probabilities", "relabel"]


def block_probabilities(
    pred_paths: Iterable[str | os.PathLike[str]],
    n_points: int,
    *,
    block: str | None = None,
    block_path: str | os.PathLike[str] = "<block>",
) -> tuple[np.ndarray, dict[str, Any]]:
    """Per-point tower probability of one block from its prediction files.

    Parameters
    ----------
    pred_paths
        Prediction files (:mod:`towerpipe.io.predictions`); only rows whose source block is
        ``block`` are used.
    n_points
        Number of points of the block file.
    block
        Block name as in the prediction files' ``meta["blocks"]``; default: the common
        ``meta["block"]`` of the prediction files.
    block_path
        For error messages.

    Returns
    -------
    prob
        ``(n_points,)`` float32, 0 where no prediction; duplicates combined with max.
    info
        ``block``, ``pred_files``, ``pred_points``.
    """
    preds = [(Path(p), load_pred(p)) for p in pred_paths]
    if block is None:
        names = sorted({str(pf.meta.get("block")) for _, pf in preds})
        if len(names) > 1:
            raise InputError(block_path, f"prediction files belong to several blocks {names}; pass block=")
        block = names[0] if names else None
    prob = np.zeros(n_points, dtype=np.float32)
    n_rows = 0
    for path, pf in preds:
        rows = pf.for_block(block) if block is not None else {k: v[:0] for k, v in pf.arrays.items()}
        idx, p = rows["point_index"], rows["prob"]
        if len(idx) == 0:
            continue
        if idx.min() < 0 or idx.max() >= n_points:
            raise InputError(
                path,
                f"point_index out of range for block {block!r} ({n_points} points in {block_path}); "
                "the prediction file is stale: rerun preprocessing and inference",
            )
        if not np.isfinite(p).all():
            raise InputError(path, "non-finite tower probabilities; rerun the inference")
        np.maximum.at(prob, idx, p) if _has_duplicates(idx) else _assign_max(prob, idx, p)
        n_rows += len(idx)
    return prob, {"block": block, "pred_files": len(preds), "pred_points": n_rows}


def _has_duplicates(idx: np.ndarray) -> bool:
    s = np.sort(idx)
    return bool(len(s) > 1 and (s[1:] == s[:-1]).any())


def _assign_max(prob: np.ndarray, idx: np.ndarray, p: np.ndarray) -> None:
    prob[idx] = np.maximum(prob[idx], p)


def relabel(
    classification: np.ndarray,
    prob: np.ndarray,
    threshold: float,
    *,
    tower: np.ndarray | None = None,
    withheld: np.ndarray | None = None,
) -> np.ndarray:
    """New ASPRS classes from input classes and tower probabilities.

    ``prob >= threshold`` → 15 (or, when given, the points of reported towers
    ``tower``); input 15 otherwise → 1; everything else unchanged. Points whose LAS
    *withheld* flag is set (``withheld``) keep their class whatever it is: they were never
    processed. Works on plain class values (not the packed 1.2 byte).
    """
    if tower is None:
        tower = prob >= threshold
    out = np.where(classification == classes.TOWER, classes.OTHER, classification).astype(classification.dtype)
    out[tower] = classes.TOWER
    if withheld is not None and withheld.any():
        out[withheld] = classification[withheld]
    return out


@dataclass(frozen=True)
class BlockLabels:
    """What the merge writes into each point of a block (:func:`block_labels`).

    Attributes
    ----------
    prob
        ``(n_points,)`` float32 tower probability (``TowerProbability``), 0 where no prediction.
    tower_ids
        ``(n_points,)`` uint64 ``tower_id`` of the reported tower a point belongs to
        (``TowerpipeTowerId``), 0 elsewhere.
    tower
        ``(n_points,)`` bool, the points of reported towers; ``None`` without tower-points
        files (the threshold decides).
    info
        ``block``, ``pred_files``, ``pred_points`` (:func:`block_probabilities`).
    """

    prob: np.ndarray
    tower_ids: np.ndarray
    tower: np.ndarray | None
    info: dict[str, Any]

    def classes(
        self, classification: np.ndarray, threshold: float, start: int = 0, *, withheld: np.ndarray | None = None
    ) -> np.ndarray:
        """The output classes of the points ``start, start + 1, ...`` of the block (:func:`relabel`).

        Parameters
        ----------
        classification
            Their input classes (plain class values, not the packed 1.2 byte).
        threshold
            Tower probability threshold (used when there are no tower-points files).
        start
            Index of the first of them in the block (the merge relabels chunk by chunk).
        withheld
            Their LAS *withheld* flags: those points keep their class.
        """
        stop = start + len(classification)
        tower = None if self.tower is None else self.tower[start:stop]
        return relabel(classification, self.prob[start:stop], threshold, tower=tower, withheld=withheld)


def block_labels(
    pred_paths: Iterable[str | os.PathLike[str]],
    n_points: int,
    *,
    block: str | None = None,
    block_path: str | os.PathLike[str] = "<block>",
    tower_points: Sequence[str | os.PathLike[str]] | None = None,
) -> BlockLabels:
    """Which probability, tower id and class each point of a block gets in the merge.

    Parameters
    ----------
    pred_paths, n_points, block, block_path
        As for :func:`block_probabilities`.
    tower_points
        Tower-points files (:func:`towerpipe.io.members.save_members`): Classification 15
        goes to exactly the points of those towers, and the tower ids are theirs. ``None``:
        every point at or above the threshold is 15, and the tower id is 0 everywhere.
    """
    prob, info = block_probabilities(pred_paths, n_points, block=block, block_path=block_path)
    if tower_points is not None:
        from towerpipe.io.members import member_ids

        tower_ids = member_ids(tower_points, str(block if block is not None else info["block"]), n_points)
        tower = tower_ids > 0
    else:
        tower_ids, tower = np.zeros(n_points, dtype=np.uint64), None
    return BlockLabels(prob, tower_ids, tower, info)
