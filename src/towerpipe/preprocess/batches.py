"""Batches: a zone of small blocks runs as jobs of several neighbouring blocks.

A job of a small block spends most of its time starting Python and importing the libraries it
is built on (docs/scale.md: three quarters of the 5 s of job time of a 2,000-point block). So a
zone whose blocks are all small (one tile each, at most ``batch.block_points`` points) is planned
in batches: the blocks of a cell of a fixed grid, about ``batch.blocks`` blocks, cut into runs of
at most ``batch.points`` points where a cell holds more. Each batch is one inference job (every
block's preprocessing and inference, rule ``infer_batch``) and one products job (every block's
towers, classified LAZ and QA page, rule ``products_batch``), which call the per-block steps
block after block, with the same arguments as the per-block jobs: the products are the same.

The decision is per zone, all or nothing, so a block's neighbours are always batched like it:
a zone with one block of two tiles or of more points than ``block_points`` keeps a job per
tile and per block for every block. A block that could not be split is never batched: its
towers job fails with the recorded error, as in a zone without batches, and only that block
is missing from the published zone. The workflow also runs a zone block by block when its
model cannot run on one of its blocks (the model choice's ``incompatible_blocks``), so that
block fails alone too.

The splits come before the plan, so they are batched by the blocks' headers
(:func:`split_batches`, rule ``split_batch``): the same grid, one job decoding the blocks of a
cell into their caches, each block's failure recorded in its own cache as its own split job
records it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from towerpipe.config import Section

#: A batch's id: ``b``, then the column and row of its cell (:func:`batch_blocks`) …
BATCH_ID = "b{ix}_{iy}"
#: … and, for a cell cut into several batches, the run's number.
RUN_SUFFIX = "_{run}"


@dataclass(frozen=True)
class BatchConfig(Section):
    """The ``batch`` section: when and how a zone's blocks run in batches."""

    SECTION: ClassVar[str] = "batch"

    #: A zone is batched when each of its blocks has one tile and at most this many points (0: never).
    block_points: int
    #: Points of a batch at most.
    points: int
    #: Blocks of a batch at most.
    blocks: int


def morton(ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """Z-order key of non-negative integer cells (below 2^32 a side): nearby cells, nearby keys."""

    def spread(v: np.ndarray) -> np.ndarray:  # bit i of v to bit 2i
        v = np.asarray(v).astype(np.uint64) & np.uint64(0xFFFFFFFF)
        for shift, mask in (
            (16, 0x0000FFFF0000FFFF),
            (8, 0x00FF00FF00FF00FF),
            (4, 0x0F0F0F0F0F0F0F0F),
            (2, 0x3333333333333333),
            (1, 0x5555555555555555),
        ):
            v = (v | (v << np.uint64(shift))) & np.uint64(mask)
        return v

    return spread(ix) | (spread(iy) << np.uint64(1))


def batch_blocks(blocks: Mapping[str, Mapping[str, Any]], config: BatchConfig) -> dict[str, list[str]]:
    """The zone's batches: batch id → its blocks (in Z-order), or ``{}`` for a zone not batched.

    The blocks are grouped by the cells of a grid fixed in the zone's coordinates, of
    ``floor(sqrt(config.blocks))`` median blocks a side: a block added to the zone later
    changes only its cell's batch (and the products of the batches beside it, which read its
    predictions), never the others'. A cell of more than ``config.points`` points (or blocks)
    is cut, in Z-order of its blocks, into as few even runs as the limits allow.

    Parameters
    ----------
    blocks
        Block id → its plan (:func:`towerpipe.preprocess.tiling.plan_zone`): ``tiles``,
        ``points``, ``bounds`` (``None`` for a block that could not be split).
    config
        The limits (:class:`BatchConfig`).

    Returns
    -------
    dict
        Batch id (:data:`BATCH_ID`: its cell, and its run within the cell when the cell is cut)
        → block ids, sorted by id. Empty unless every block with points has one tile and at
        most ``config.block_points`` points, and some batch gets several blocks; a block
        without points is in no batch.
    """
    split = {b: m for b, m in blocks.items() if m.get("bounds") is not None and m.get("tiles")}
    if config.block_points <= 0 or len(split) < 2:
        return {}
    if any(len(m["tiles"]) != 1 or int(m.get("points", 0)) > config.block_points for m in split.values()):
        return {}
    return _grid_batches({b: (m["bounds"], int(m.get("points", 0))) for b, m in split.items()}, config)


def split_batches(headers: Mapping[str, Mapping[str, Any] | None], config: BatchConfig) -> dict[str, list[str]]:
    """The zone's split batches: batch id → the blocks one split job decodes, or ``{}``.

    The split comes before the plan, so its batches are drawn from the blocks' headers, on the
    grid of :func:`batch_blocks` (the same ids where the headers tell the truth). A zone whose
    headers announce at most ``config.block_points`` points for every block is split in
    batches; a block whose header cannot be read, or announces no point, has a split job of
    its own (which records why it cannot be read, :func:`towerpipe.preprocess.split.split_block`).
    A split batch records each block's failure in its own cache, as the split job of one block
    does: a block that cannot be read fails alone.

    Parameters
    ----------
    headers
        Block id → its header record (:class:`towerpipe.io.inputs.BlockInput`'s ``header``:
        ``bounds``, ``point_count``), or ``None`` when unreadable.
    config
        The limits (:class:`BatchConfig`).
    """
    known = {b: h for b, h in headers.items() if h and h.get("bounds") and int(h.get("point_count") or 0) > 0}
    if config.block_points <= 0 or len(known) < 2:
        return {}
    if any(int(h["point_count"]) > config.block_points for h in known.values()):
        return {}
    return _grid_batches({b: (h["bounds"], int(h["point_count"])) for b, h in known.items()}, config)


def _grid_batches(blocks: Mapping[str, tuple[Sequence[float], int]], config: BatchConfig) -> dict[str, list[str]]:
    """Blocks (id → bounds, points) grouped by the cells of the zone's grid, cut into runs
    (:func:`batch_blocks`); ``{}`` when no batch gets several blocks."""
    ids = sorted(blocks)
    b = np.array([blocks[i][0] for i in ids], dtype=np.float64)
    cx, cy = (b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2
    points = np.array([blocks[i][1] for i in ids], dtype=np.int64)
    # a unit of the median block's side in whole metres (delivered tiles are; the points' bounds
    # fall a little short of the tile's): a grid of equal blocks gets one unit per block, and a
    # block added later leaves the grid as it was
    w = max(round(float(np.median(b[:, 2] - b[:, 0]))), 1)
    h = max(round(float(np.median(b[:, 3] - b[:, 1]))), 1)
    bx, by = np.floor(cx / w).astype(np.int64), np.floor(cy / h).astype(np.int64)
    side = max(1, math.isqrt(config.blocks))  # blocks a side of a batch's cell
    gx, gy = np.floor_divide(bx, side), np.floor_divide(by, side)
    order = np.lexsort((np.arange(len(ids)), morton(bx - bx.min(), by - by.min()), gx, gy))
    out: dict[str, list[str]] = {}
    for (ix, iy), members in itertools.groupby(order, key=lambda k: (int(gx[k]), int(gy[k]))):
        cell = np.fromiter(members, dtype=np.int64)
        runs = _runs(cell, points, config)
        for r, run in enumerate(runs):
            suffix = RUN_SUFFIX.format(run=r) if len(runs) > 1 else ""
            out[BATCH_ID.format(ix=ix, iy=iy) + suffix] = [ids[k] for k in run]
    if all(len(r) == 1 for r in out.values()):
        return {}
    return dict(sorted(out.items()))


def _runs(cell: np.ndarray, points: np.ndarray, config: BatchConfig) -> list[np.ndarray]:
    """A cell's blocks (indices, in Z-order) cut into as few runs of even points as the limits
    allow (a block of more than ``config.points`` points alone)."""
    n_runs = max(math.ceil(len(cell) / config.blocks), math.ceil(int(points[cell].sum()) / config.points))
    cum = np.cumsum(points[cell])
    while True:
        cuts = np.searchsorted(cum, cum[-1] * np.arange(1, n_runs) / n_runs, side="right")
        runs = [r for r in np.split(cell, cuts) if len(r)]
        if n_runs >= len(cell) or all(
            len(r) <= config.blocks and (len(r) == 1 or int(points[r].sum()) <= config.points) for r in runs
        ):
            return runs
        n_runs += 1


def batch_neighbours(batch: Sequence[str], plan: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The other batches whose blocks a batch's blocks have as neighbours (sorted)."""
    own = {plan[b]["batch"] for b in batch}
    return sorted({plan[n]["batch"] for b in batch for n in plan[b]["neighbours"]} - own - {None})
