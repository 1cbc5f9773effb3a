"""Where the data is around a tower: the context its conductor support is judged in.

:class:`Coverage` knows where points exist (occupied cells of a grid), where the survey
reaches (the measured bounds of the block and its neighbours) and, from that, which of the
straight lines through a tower would show in its conductor ring (:meth:`Coverage.lines_seen`,
``towers.wire_line_coverage``). :class:`TileContext` gives the towers job, for a tower's
centre, the points of the tile that holds it with their coverage, and the conductor points
found over that tile by the tiles' own wire search (:func:`towerpipe.towers.wires.wire_support`
reads them).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["Coverage", "TileContext", "tile_density"]


class Coverage:
    """Where a set of points exists: the occupied cells of a square grid.

    Parameters
    ----------
    x, y
        The points (all of them: ground too).
    cell
        Cell size (m).
    grow
        Cells added around the occupied ones: a location within about ``grow * cell``
        of a point counts as covered (the radial bins are tested at their centres).
    survey, min_line_share
        The surveyed area around (boxes: the measured bounds of the block and its
        neighbours, beyond the points loaded here) and the share of the lines through a
        tower that must show in its ring for a support to be judged (see :meth:`lines_seen`
        and :func:`wire_support`).
    """

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        cell: float = 10.0,
        grow: int = 1,
        survey: Sequence[Sequence[float]] = (),
        min_line_share: float = 0.0,
    ):
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        self.cell = float(cell)
        self.survey = [tuple(map(float, b)) for b in survey]
        self.min_line_share = float(min_line_share)
        if len(x) == 0:
            self.origin, self.mask = (0.0, 0.0), np.zeros((0, 0), dtype=bool)
            return
        self.origin = (float(np.floor(x.min())), float(np.floor(y.min())))
        ix = ((x - self.origin[0]) // self.cell).astype(np.int64)
        iy = ((y - self.origin[1]) // self.cell).astype(np.int64)
        self.origin = (self.origin[0] - grow * self.cell, self.origin[1] - grow * self.cell)
        ix, iy = ix + grow, iy + grow
        mask = np.zeros((int(iy.max()) + 1 + grow, int(ix.max()) + 1 + grow), dtype=bool)
        mask[iy, ix] = True
        if grow:
            from scipy.ndimage import binary_dilation

            mask = binary_dilation(mask, iterations=grow)
        self.mask = mask

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether each location lies in an occupied cell."""
        ix = np.floor((np.asarray(x) - self.origin[0]) / self.cell).astype(np.int64)
        iy = np.floor((np.asarray(y) - self.origin[1]) / self.cell).astype(np.int64)
        ny, nx = self.mask.shape
        ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        out = np.zeros(np.shape(ix), dtype=bool)
        out[ok] = self.mask[iy[ok], ix[ok]]
        return out

    def surveyed(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether each location lies in the surveyed area (every location when none is given)."""
        x, y = np.asarray(x), np.asarray(y)
        if not self.survey:
            return np.ones(np.shape(x), dtype=bool)
        return np.any([(x >= b[0]) & (x <= b[2]) & (y >= b[1]) & (y <= b[3]) for b in self.survey], axis=0)

    def lines_seen(self, bx: np.ndarray, by: np.ndarray, min_bins: int) -> float:
        """Share of the straight lines through a tower that its ring shows in the surveyed area.

        ``bx, by`` are the ring's radial bin centres of sectors at equal angular steps over the
        full circle (one row per sector, :func:`wire_support`'s). A line through the tower
        leaves it in two opposite sectors; it shows when one of them has ``min_bins`` bins in
        the surveyed area. Returns the share of the line directions that show (1.0 where no
        survey is given): at a zone's straight edge every line shows through the inner
        half of the ring, at its corner about half of them, in a corridor strip crossing the
        line those along the strip only.
        """
        seen = self.surveyed(bx, by).sum(axis=1) >= min_bins
        half = len(seen) // 2
        return float((seen[:half] | seen[half : 2 * half]).mean()) if half else 1.0


def tile_density(meta: Mapping[str, Any]) -> float:
    """A tile's flight density: all its core points (ground included) a square metre of its core box,
    as the shape verifier's training measures it (:mod:`towerpipe.training.verifier`); NaN unknown."""
    core = (meta.get("counts") or {}).get("core")
    bounds = meta.get("core_bounds")
    if core is None or not bounds:
        return float("nan")
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    return float(core) / max((xmax - xmin) * (ymax - ymin), 1.0)


class TileContext:
    """``context(cx, cy)`` for :func:`towerpipe.towers.extract.extract_towers`: the model-input
    points of the tile whose core holds ``(cx, cy)``, and where the tile has points
    (:class:`Coverage` of all its points, ground included).

    Tiles without points (a block whose split failed) are skipped, so they never hide the
    tile of a neighbour that holds the same place.

    Tiles are read lazily (only ``x, y, z, hag, model_input``) and the ``keep_tiles`` read
    last are kept: the towers job visits its clusters in label order, not tile by tile, and
    keeping only the last tile read one tile again for nearly every cluster (240 reads of 4
    tiles on the 1 km² benchmark block, 35 of its 58 s).

    The arrays also hold ``"density"``, the tile's flight density (:func:`tile_density`), and
    ``"conductors"``: the wire points within the tile's extent (core and
    buffer), each judged in the tile whose core holds it
    (:func:`towerpipe.towers.wires.tile_conductor_points`, with the points around it on every
    side), with ``"direction"`` the plan direction of its wire. They are read from the
    conductor-points file each tile's inference job writes beside it
    (:func:`towerpipe.io.workdir.conductors_of`) or, for a tile without one (a zone only
    prepared), found here the same way.

    Parameters
    ----------
    tile_paths
        Tile files (:mod:`towerpipe.io.tiles`) of the block.
    survey, min_line_share
        See :class:`Coverage`: a tower through which a line could leave where the surveyed
        boxes show none of its ring gets an unknown support (kept, and flagged by the QA).
    keep_tiles
        How many tiles are kept in memory (the least recently used is dropped): a block's
        own tiles (4 for a 1 km block of 500 m tiles) are then read once.
    """

    _COLUMNS = ["x", "y", "z", "hag", "model_input"]

    def __init__(
        self,
        tile_paths: Sequence[str],
        *,
        survey: Sequence[Sequence[float]] = (),
        min_line_share: float = 0.0,
        keep_tiles: int = 4,
    ):
        from towerpipe.io.columns import read_meta

        self._survey, self._min_line_share = [b for b in survey if b], min_line_share
        self._keep = max(int(keep_tiles), 1)
        self.reads = 0  # tile files read so far
        self._tiles = []
        self._density: dict[str, float] = {}  # path -> the tile's points a square metre of its core
        for p in tile_paths:
            meta = read_meta(p)
            core = meta.get("core_bounds")
            if core and meta.get("failed") is None and (meta.get("counts") or {}).get("points", 1) > 0:
                self._tiles.append((str(p), core))
                self._density[str(p)] = tile_density(meta)
        # path -> (model-input arrays and the conductors over the tile, coverage), least recently used first
        self._cached: OrderedDict[str, tuple[dict[str, Any], Coverage]] = OrderedDict()
        self._conductors: dict[str, dict[str, np.ndarray]] = {}  # path -> the conductor points of its core

    def __call__(self, cx: float, cy: float) -> tuple[dict[str, Any], Coverage] | None:
        from towerpipe.io.tiles import load_tile

        for path, (xmin, ymin, xmax, ymax) in self._tiles:
            if xmin <= cx < xmax and ymin <= cy < ymax:
                if path in self._cached:
                    self._cached.move_to_end(path)
                else:
                    arrays = load_tile(path, columns=self._COLUMNS).arrays
                    self.reads += 1
                    keep = np.asarray(arrays.pop("model_input"), dtype=bool)
                    cover = Coverage(arrays["x"], arrays["y"], survey=self._survey, min_line_share=self._min_line_share)
                    points: dict[str, Any] = {k: v[keep] for k, v in arrays.items()}
                    box = (
                        float(arrays["x"].min()),
                        float(arrays["y"].min()),
                        float(arrays["x"].max()),
                        float(arrays["y"].max()),
                    )
                    points["conductors"] = self._conductors_within(box)
                    points["density"] = self._density[path]
                    self._cached[path] = (points, cover)
                    while len(self._cached) > self._keep:
                        self._cached.popitem(last=False)
                return self._cached[path]
        return None

    def _conductors_within(self, box: tuple[float, float, float, float]) -> dict[str, np.ndarray]:
        """The conductor points of every tile whose core meets ``box``, within it (``x, y, z, hag``
        and ``direction``, their wires' unit plan directions)."""
        from towerpipe.io.conductors import CONDUCTOR_ARRAYS
        from towerpipe.towers.wires import conductor_directions

        xmin, ymin, xmax, ymax = box
        parts = []
        for path, (cx0, cy0, cx1, cy1) in self._tiles:
            if cx0 > xmax or cx1 < xmin or cy0 > ymax or cy1 < ymin:
                continue
            c = self._tile_conductors(path)
            inside = (c["x"] >= xmin) & (c["x"] <= xmax) & (c["y"] >= ymin) & (c["y"] <= ymax)
            parts.append({k: v[inside] for k, v in c.items()})
        out = {k: np.concatenate([p[k] for p in parts]) if parts else np.empty(0) for k in CONDUCTOR_ARRAYS}
        out["direction"] = conductor_directions(out["direction_deg"]).reshape(-1, 2)
        return out

    def _tile_conductors(self, path: str) -> dict[str, np.ndarray]:
        """The conductor points of a tile's core: its file, or found from the tile."""
        if path not in self._conductors:
            from towerpipe.io.conductors import load_conductors
            from towerpipe.io.tiles import load_tile
            from towerpipe.io.workdir import conductors_of
            from towerpipe.towers.wires import CONDUCTOR_INPUT_COLUMNS, tile_conductor_points

            wires = conductors_of(path)
            if wires.is_file():
                self._conductors[path] = load_conductors([wires])
            else:
                arrays = load_tile(path, columns=list(CONDUCTOR_INPUT_COLUMNS)).arrays
                self._conductors[path] = tile_conductor_points(arrays)
        return self._conductors[path]
