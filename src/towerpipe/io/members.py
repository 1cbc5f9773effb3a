"""Tower-points files: the points of the towers a towers job accepts, and their tower ids.

A towers job (:func:`towerpipe.jobs.steps.towers_step`) writes the points of every accepted
tower with points in its block (:func:`save_members`); the merge classifies them 15 and
writes their tower id (:func:`member_ids`), the block's QA reads them.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from towerpipe.errors import InputError
from towerpipe.io.columns import load_columns, save_columns, validate_columns

#: Arrays of a tower-points file: the points (in any block) of the accepted towers that have
#: points in one block, ``block_id`` indexing ``meta["blocks"]`` and ``tower`` indexing
#: ``meta["towers"]``.
MEMBER_ARRAYS: dict[str, np.dtype] = {
    "block_id": np.dtype("i4"),
    "point_index": np.dtype("i8"),
    "tower": np.dtype("i4"),
}


def save_members(path: str | os.PathLike[str], members: Mapping[int, tuple[np.ndarray, np.ndarray]]) -> None:
    """Write the points of reported towers (``extract_towers(...).members``) atomically.

    ``meta["towers"]`` lists the (integer) tower ids that ``tower`` indexes.
    """
    ids = sorted(int(t) for t in members)
    names = sorted({str(b) for bl, _ in members.values() for b in np.asarray(bl).tolist()})
    code = {b: i for i, b in enumerate(names)}
    parts = {k: [] for k in MEMBER_ARRAYS}
    for t, tid in enumerate(ids):
        bl, idx = members[tid]
        parts["block_id"].append(np.array([code[str(b)] for b in np.asarray(bl).tolist()], dtype=np.int32))
        parts["point_index"].append(np.asarray(idx, dtype=np.int64))
        parts["tower"].append(np.full(len(idx), t, dtype=np.int32))
    arrays = {
        k: (np.concatenate(v) if v else np.empty(0, d)).astype(d)
        for (k, d), v in zip(MEMBER_ARRAYS.items(), parts.values())
    }
    save_columns(path, arrays, {"blocks": names, "towers": ids})


def member_ids(paths: Sequence[str | os.PathLike[str]], block: str, n_points: int) -> np.ndarray:
    """``(n_points,)`` uint64: the ``tower_id`` of each point of ``block`` in a reported tower, 0 elsewhere.

    Parameters
    ----------
    paths
        Tower-points files (:func:`save_members`), e.g. the block's own (every accepted
        tower with points in the block, whichever block reports it).
    block
        The block's name.
    n_points
        Points in the block file.
    """
    out = np.zeros(int(n_points), dtype=np.uint64)
    for idx, ids in _block_members(paths, block, n_points):
        out[idx] = ids
    return out


def member_counts(paths: Sequence[str | os.PathLike[str]], block: str, n_points: int) -> dict[int, int]:
    """Points of ``block`` in each reported tower (``tower_id`` → points), as :func:`member_ids`
    labels them, without an array of the block's size."""
    parts = list(_block_members(paths, block, n_points))
    if not parts:
        return {}
    idx = np.concatenate([i for i, _ in parts])
    ids = np.concatenate([t for _, t in parts])
    # a point listed again (a later file) takes the later tower, as in member_ids
    last = len(idx) - 1 - np.unique(idx[::-1], return_index=True)[1]
    tid, n = np.unique(ids[last], return_counts=True)
    return {int(t): int(c) for t, c in zip(tid, n, strict=True)}


def _block_members(
    paths: Sequence[str | os.PathLike[str]], block: str, n_points: int
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``(point_index, tower_id)`` of the points of ``block`` in each tower-points file, checked."""
    for p in paths:
        arrays, meta = load_columns(p, list(MEMBER_ARRAYS), "tower-points", "rerun the towers_block job")
        validate_columns(arrays, MEMBER_ARRAYS, p, "tower-points", "rerun the towers_block job")
        names = list(meta.get("blocks") or [])
        if block not in names:
            continue
        try:
            ids = np.asarray([int(t) for t in meta.get("towers") or []], dtype=np.uint64)
        except (TypeError, ValueError) as exc:
            raise InputError(
                p, f"tower ids are not integers ({exc}): the file is from an older version; rerun the towers_block job"
            ) from exc
        sel = arrays["block_id"] == names.index(block)
        idx, tower = arrays["point_index"][sel], arrays["tower"][sel]
        if len(idx) and (idx.min() < 0 or idx.max() >= n_points):
            raise InputError(
                p,
                f"point_index out of range for block {block!r} ({n_points} points); the file is "
                "stale: rerun the towers_block job",
            )
        if len(tower) and (tower.min() < 0 or tower.max() >= len(ids)):
            raise InputError(p, "tower index outside meta['towers']: rerun the towers_block job")
        yield idx, ids[tower]


def member_mask(paths: Sequence[str | os.PathLike[str]], block: str, n_points: int) -> np.ndarray:
    """``(n_points,)`` bool: the points of ``block`` that belong to a reported tower (:func:`member_ids` > 0)."""
    return member_ids(paths, block, n_points) > 0
