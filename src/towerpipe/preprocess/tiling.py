"""Tiles, cores, buffers and neighbouring blocks.

Each block is cut into ``nx × ny`` equal tiles no larger than ``tile_size``
(``nx = ceil(width / tile_size)``), named ``"{ix}_{iy}"``. A point's tile is
``clip(floor((x - xmin) / tile_width), 0, nx - 1)`` (same in y), so every point
of a block is in exactly one tile *core*, points on or beyond the header's
edges included, and no sliver tiles appear when a block is a hair wider than
a multiple of ``tile_size``. A tile's *buffer* is every point of the block *and
of neighbouring blocks* within ``buffer`` metres of the core square that is not
in the core.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from towerpipe.preprocess.batches import BatchConfig, batch_blocks

Bounds = tuple[float, float, float, float]  # xmin, ymin, xmax, ymax


@dataclass(frozen=True)
class TileGrid:
    """The tiles of one block.

    Parameters
    ----------
    bounds
        The block's ``(xmin, ymin, xmax, ymax)`` (from its header).
    tile_size
        Largest tile side in metres.
    """

    bounds: Bounds
    tile_size: float

    @property
    def shape(self) -> tuple[int, int]:
        xmin, ymin, xmax, ymax = self.bounds
        nx = max(1, math.ceil((xmax - xmin) / self.tile_size - 1e-9))
        ny = max(1, math.ceil((ymax - ymin) / self.tile_size - 1e-9))
        return nx, ny

    @property
    def cell(self) -> tuple[float, float]:
        xmin, ymin, xmax, ymax = self.bounds
        nx, ny = self.shape
        return max(xmax - xmin, 1e-9) / nx, max(ymax - ymin, 1e-9) / ny

    def ids(self) -> list[str]:
        """Tile names, row-major."""
        nx, ny = self.shape
        return [f"{ix}_{iy}" for iy in range(ny) for ix in range(nx)]

    def core_box(self, tile: str) -> Bounds:
        """Nominal core square of a tile."""
        ix, iy = parse_tile_id(tile)
        w, h = self.cell
        x0, y0 = self.bounds[0] + ix * w, self.bounds[1] + iy * h
        return (x0, y0, x0 + w, y0 + h)

    def index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tile column and row of each point (clipped into the grid)."""
        nx, ny = self.shape
        w, h = self.cell
        ix = np.clip(np.floor((np.asarray(x) - self.bounds[0]) / w), 0, nx - 1).astype(np.int32)
        iy = np.clip(np.floor((np.asarray(y) - self.bounds[1]) / h), 0, ny - 1).astype(np.int32)
        return ix, iy

    def core_mask(self, x: np.ndarray, y: np.ndarray, tile: str) -> np.ndarray:
        """Points of the block that belong to ``tile``'s core."""
        tx, ty = parse_tile_id(tile)
        ix, iy = self.index(x, y)
        return (ix == tx) & (iy == ty)


def tile_ids(bounds: Bounds, tile_size: float) -> list[str]:
    """Names of a block's tiles (see :class:`TileGrid`)."""
    return TileGrid(tuple(bounds), tile_size).ids()


def parse_tile_id(tile: str) -> tuple[int, int]:
    """``"1_3"`` → ``(1, 3)``."""
    ix, iy = tile.rsplit("_", 1)
    return int(ix), int(iy)


def expand(bounds: Bounds, margin: float) -> Bounds:
    xmin, ymin, xmax, ymax = bounds
    return (xmin - margin, ymin - margin, xmax + margin, ymax + margin)


def intersects(a: Bounds, b: Bounds) -> bool:
    """Closed-box intersection test."""
    return a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]


def neighbours(block: str, all_bounds: Mapping[str, Bounds], margin: float) -> list[str]:
    """Other blocks whose bounds come within ``margin`` of ``block``'s bounds (sorted)."""
    box = expand(all_bounds[block], margin)
    return sorted(b for b, bb in all_bounds.items() if b != block and intersects(box, bb))


def blocks_for_tile(
    block_bounds: Bounds, tile: str, tile_size: float, buffer: float, all_bounds: Mapping[str, Bounds]
) -> list[str]:
    """Blocks that may hold points of a tile's core or buffer (sorted)."""
    box = expand(TileGrid(tuple(block_bounds), tile_size).core_box(tile), buffer)
    return sorted(b for b, bb in all_bounds.items() if intersects(box, bb))


def box_mask(x: np.ndarray, y: np.ndarray, box: Bounds) -> np.ndarray:
    """Points inside a closed box."""
    return (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])


def occupied_tiles(grid: TileGrid, x: np.ndarray, y: np.ndarray, chunk: int = 4_000_000) -> list[str]:
    """Ids of the tiles of ``grid`` that hold at least one of the points (row-major).

    A stray point far from the others widens the grid but adds one tile, not the
    thousands of empty ones between.
    """
    nx, ny = grid.shape
    cells: set[int] = set()
    for start in range(0, len(x), chunk):
        ix, iy = grid.index(x[start : start + chunk], y[start : start + chunk])
        flat = iy.astype(np.int64) * nx + ix
        if nx * ny <= 1 << 20:  # a count per tile: one pass, no sort (a block has a few tiles)
            cells.update(np.flatnonzero(np.bincount(flat, minlength=nx * ny)).tolist())
        else:  # a grid widened by a stray point: the occupied tiles only
            cells.update(np.unique(flat).tolist())
    return [f"{c % nx}_{c // nx}" for c in sorted(cells)]


def plan_zone(blocks: Mapping[str, Mapping], tile_size: float, buffer: float, batch: BatchConfig | None = None) -> dict:
    """The zone's jobs from what the split measured (never from the headers).

    Parameters
    ----------
    blocks
        Block id → split metadata: ``bounds`` (of the points) and ``tiles`` (occupied
        tile ids), or ``error`` for a block that could not be split (it gets no tiles;
        its ``header_bounds``, when known, only name it as a missing neighbour).
    tile_size, buffer
        The preprocessing's tile size and buffer (m).
    batch
        When and how small blocks are grouped into batches (:mod:`towerpipe.preprocess.batches`;
        ``None``: never).

    Returns
    -------
    dict
        ``{"blocks": {id: {"tiles", "points", "bounds", "neighbours", "tile_blocks":
        {tile: [ids]}, "missing_neighbours": [ids], "batch": id or None}}, "batches": {id:
        [ids]}}``; ``tile_blocks`` lists the block itself first, then the blocks with an
        occupied tile within ``buffer`` of the tile's core.
    """
    from shapely import box as shp_box
    from shapely.strtree import STRtree

    boxes, owners = [], []
    grids = {}
    for b, m in blocks.items():
        if m.get("error") or not m.get("tiles"):
            continue
        grids[b] = TileGrid(tuple(m["bounds"]), tile_size)
        for t in m["tiles"]:
            boxes.append(grids[b].core_box(t))
            owners.append(b)
    tree = STRtree([shp_box(*bx) for bx in boxes]) if boxes else None
    failed = {b: m.get("header_bounds") for b, m in blocks.items() if m.get("error")}
    out: dict[str, dict] = {}
    for b, m in blocks.items():
        if b not in grids:
            out[b] = {
                "tiles": [],
                "points": 0,
                "bounds": None,
                "neighbours": [],
                "tile_blocks": {},
                "missing_neighbours": [],
            }
            continue
        tile_blocks = {}
        for t in m["tiles"]:
            near = expand(grids[b].core_box(t), buffer)
            hits = {owners[i] for i in tree.query(shp_box(*near))} - {b}
            tile_blocks[t] = [b, *sorted(hits)]
        reach = expand(tuple(m["bounds"]), buffer)
        out[b] = {
            "tiles": list(m["tiles"]),
            "points": int(m.get("points", 0)),
            "bounds": list(m["bounds"]),
            "neighbours": sorted({n for v in tile_blocks.values() for n in v[1:]}),
            "tile_blocks": tile_blocks,
            "missing_neighbours": sorted(f for f, hb in failed.items() if hb and intersects(reach, tuple(hb))),
        }
    batches = batch_blocks(out, batch) if batch is not None else {}
    of = {b: i for i, bs in batches.items() for b in bs}
    for b, p in out.items():
        p["batch"] = of.get(b)
    return {"tile_size": tile_size, "buffer": buffer, "blocks": out, "batches": batches}


def plan_zone_step(
    cache_dirs: Mapping[str, str], out_json: str, *, tile_size: float, buffer: float, batch: BatchConfig | None = None
) -> dict:
    """:func:`plan_zone` from the split caches' ``meta.json`` → ``out_json`` (written atomically)."""
    import json

    from towerpipe.io.atomic import write_text_atomic
    from towerpipe.io.blockcache import BlockCache

    metas = {b: BlockCache(d).read_meta() for b, d in cache_dirs.items()}
    plan = plan_zone(metas, tile_size, buffer, batch)
    write_text_atomic(out_json, json.dumps(plan, indent=0, sort_keys=True))
    return {
        "blocks": len(metas),
        "tiles": sum(len(v["tiles"]) for v in plan["blocks"].values()),
        "batches": len(plan["batches"]),
    }
