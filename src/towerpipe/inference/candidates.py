"""Square windows centred on candidate objects: the height peaks of a tile (:func:`candidate_windows`).

A tower is the highest thing within its own crossarm reach: its crossarms hang lower and
the conductors sag away from it. The local maxima of the tile's height raster (the
highest height above ground per :data:`PEAK_RES` cell, each the maximum within
:data:`PEAK_RADIUS`) at or above ``min_height`` are therefore the candidates, and each gets a
window centred on it. Overhead wires make no peak (``exclude``; the inference passes
:func:`towerpipe.inference.wire_mask.overhead_wires`): a conductor of another line passing over a lower
tower, or rising with the terrain beside it, is higher than that tower's top. Towers then
sit at a window's centre, as in training, and the classifier sees fewer windows than the
grid sends it (a forest gives one candidate per crown cluster, open land none). The raster
lives on a global grid and a candidate's window reaches at most ``window / 2 + PEAK_RADIUS``
from it, within the tile buffer, so a tower near a tile edge gives the same window in both
tiles that see it.

A tower among higher crowns has no peak within :data:`PEAK_RADIUS`. With a
``secondary_radius``, the peaks within that smaller radius that are not peaks within
:data:`PEAK_RADIUS` become *secondary* candidates, each with a ``reach``: the inference
segments such a window only farther than :data:`PEAK_RADIUS` from every segmented primary
peak (nearer, it is mostly another top of that tower), and takes its
probabilities for the points within ``reach`` of its centre only (the segmenter reads a
window's centre as the tower's place, and would paint a crown there).

The lower tower of two side by side (parallel lines 10-15 m apart) is no peak at all: its
neighbour's crossarms pass over its top. It is a *column* (:func:`stem_columns`): a place
whose points fill most of the height from :data:`STEM_FLOOR` to its top, as a lattice's body
does and a crossarm, a conductor or a roof does not. With a ``stem_gap``, the columns farther
than that from every peak (primary or secondary) become *stem* candidates
(:attr:`CandidateWindows.stem`), with a ``reach`` of ``stem_reach``; the inference segments one
only beside a tower its peak windows painted (:func:`stems_beside`). Off by default: they paint
more of the towers but also crowns and cranes beside what the segmenter painted (docs/model.md,
"The lower tower of a pair: stem windows").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "PEAK_RADIUS",
    "PEAK_RES",
    "STEM_BIN",
    "STEM_CELL",
    "STEM_FLOOR",
    "STEM_OCCUPANCY",
    "STEM_PAINTED",
    "CandidateWindows",
    "candidate_windows",
    "disk_maximum",
    "height_peaks",
    "segmented_windows",
    "stem_columns",
    "stems_beside",
]

#: Candidate windows: cell (m) of the height raster, and the radius (m) within which a
#: candidate is the highest point (a tower's crossarm reach). With the overhead wires left
#: out, every tower of the CI scene has a window centred within 3.1 m of it (28 windows);
#: 7 m gives 34 windows, and the wires left in hide 3 of its 5 tower tops. In woodland a
#: small tower with higher crowns within 10 m has no peak of its own; 7 m was measured
#: (docs/model.md, towers in woodland) and not kept: three more towers of `calib_forest`, and
#: more crowns painted beside the towers of the held-out zones. The secondary peaks of
#: :func:`candidate_windows` (``inference.secondary_radius``) add such towers' windows without
#: letting them paint around the towers the 10 m peaks find.
PEAK_RES, PEAK_RADIUS = 1.0, 10.0

#: Columns (:func:`stem_columns`): the cell (m) of their raster, the height (m above ground) from
#: which a cell's heights are counted, the step (m) of the height bins, and the share of the bins
#: between the floor and the cell's top that must hold a point. On `calib_pairs` the three lower
#: towers of its pairs that have no height peak each hold a column within 1.7 m of their centre.
STEM_CELL, STEM_FLOOR, STEM_BIN, STEM_OCCUPANCY = 1.5, 4.0, 2.0, 0.6

#: A stem window is segmented where the peak windows painted at least this many points at or above
#: this probability (the window as it is) within :data:`PEAK_RADIUS` of its centre: beside a tower.
#: Beside any segmented peak window (the classifier's gate passes crowns and cranes), stems put three
#: false objects more on the calibration zones, each 70-100 m from every tower (docs/model.md).
STEM_PAINTED = (20, 0.5)


class _WindowPoints:
    """The points a tile's candidate windows are cut from: a plan tree of them and their canonical
    order. A window's indices are found when asked for (the gates read only a few windows of a
    tile; keeping every window's indices took 0.5 s and hundreds of MB on a dense tile)."""

    def __init__(self, tree: Any, rank: np.ndarray | None) -> None:
        self.tree, self.rank = tree, rank

    def indices(self, center: np.ndarray, half: float) -> np.ndarray:
        idx = np.asarray(self.tree.query_ball_point(center, half, p=np.inf), np.int64)
        # a tile's points are gathered in their canonical order (rank None): their indices, sorted, are in it
        return np.sort(idx) if self.rank is None else idx[np.argsort(self.rank[idx], kind="stable")]


@dataclass(frozen=True)
class CandidateWindows:
    """Windows centred on the candidates of one tile (:func:`candidate_windows`).

    Attributes
    ----------
    window
        Window side (m).
    keys
        ``(W, 2)`` int64 global raster indices of the candidates (the sampler's seeds).
    centers
        ``(W, 2)`` float64 window centres.
    heights
        ``(W,)`` the candidate's height above ground (m).
    counts, core_counts
        ``(W,)`` points and core points in each window.
    reach
        ``(W,)`` distance (m, in plan) from the centre within which the window sets its points'
        probabilities (``inf``: all; a secondary or a stem candidate: its centre's points).
    stem
        ``(W,)`` bool: a stem candidate (a column, not a height peak).
    """

    window: float
    keys: np.ndarray
    centers: np.ndarray
    heights: np.ndarray
    counts: np.ndarray
    core_counts: np.ndarray
    reach: np.ndarray
    stem: np.ndarray
    _points: _WindowPoints

    def __len__(self) -> int:
        return len(self.keys)

    def center(self, i: int) -> tuple[float, float]:
        """Centre (x, y) of window ``i``."""
        return float(self.centers[i, 0]), float(self.centers[i, 1])

    def indices(self, i: int) -> np.ndarray:
        """Indices of window ``i``'s points, in the canonical order given at construction."""
        return self._points.indices(self.centers[i], self.window / 2.0)

    def select(self, mask_or_index: np.ndarray) -> CandidateWindows:
        """The selected windows."""
        sel = np.arange(len(self))[mask_or_index]
        return CandidateWindows(
            self.window,
            self.keys[sel],
            self.centers[sel],
            self.heights[sel],
            self.counts[sel],
            self.core_counts[sel],
            self.reach[sel],
            self.stem[sel],
            self._points,
        )


def disk_maximum(r: np.ndarray, radius: float, res: float = 1.0) -> np.ndarray:
    """The maximum of raster ``r`` (cells of ``res``) over a disk of ``radius`` around each cell
    (outside the raster: ``-inf``).

    Equal to ``scipy.ndimage.maximum_filter(r, footprint=disk, mode="constant", cval=-np.inf)``
    for the disk of the cells whose centres lie within ``radius``: the disk is a stack of
    horizontal runs, one per row offset, so its maximum is the largest of the row offsets' 1-D
    running maxima (one per run length), shifted by the offset. A tenth of the 2-D filter's time
    on a tile's raster.
    """
    from scipy import ndimage

    k = int(np.ceil(radius / res))
    disk = np.hypot(*np.mgrid[-k : k + 1, -k : k + 1]) * res <= radius
    count = disk.sum(axis=1)  # the run of row offset d - k: count[d] cells, centred
    widths = {int(c) for c in count if c}
    runs = {c: ndimage.maximum_filter1d(r, c, axis=1, mode="constant", cval=-np.inf) for c in widths}
    out = np.full(r.shape, -np.inf, r.dtype)
    n = r.shape[0]
    for d, c in enumerate(count.tolist()):
        s = d - k  # out[i] takes the run of row i + s
        if c and abs(s) < n:
            src = runs[int(c)]
            if s >= 0:
                np.maximum(out[: n - s], src[s:], out=out[: n - s])
            else:
                np.maximum(out[-s:], src[: n + s], out=out[-s:])
    return out


def height_peaks(
    x: np.ndarray,
    y: np.ndarray,
    hag: np.ndarray,
    *,
    min_height: float,
    radius: float = PEAK_RADIUS,
    res: float = PEAK_RES,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local maxima of the height raster at or above ``min_height``.

    Returns
    -------
    keys, centers, heights
        ``(P, 2)`` int64 global cell indices, ``(P, 2)`` float64 cell centres and ``(P,)``
        heights; a plateau of equal maxima gives one peak (its first cell in raster order).
    """
    from scipy import ndimage

    empty = (np.empty((0, 2), np.int64), np.empty((0, 2)), np.empty(0))
    tall = np.asarray(hag) >= min_height
    if not tall.any():
        return empty
    ix = np.floor(np.asarray(x) / res).astype(np.int64)
    iy = np.floor(np.asarray(y) / res).astype(np.int64)
    ox, oy = int(ix.min()), int(iy.min())
    r = np.full((int(ix.max()) - ox + 1, int(iy.max()) - oy + 1), -np.inf, np.float32)
    np.maximum.at(r, (ix - ox, iy - oy), np.asarray(hag, np.float32))
    peak = (r == disk_maximum(r, radius, res)) & (r >= min_height)
    lab, n = ndimage.label(peak, structure=np.ones((3, 3), bool))
    if n == 0:
        return empty
    first = ndimage.minimum_position(np.arange(lab.size).reshape(lab.shape), lab, np.arange(1, n + 1))
    cells = np.asarray(first, np.int64).reshape(-1, 2)
    keys = cells + [ox, oy]
    return keys, (keys + 0.5) * res, r[cells[:, 0], cells[:, 1]].astype(np.float64)


def stem_columns(
    x: np.ndarray,
    y: np.ndarray,
    hag: np.ndarray,
    *,
    min_height: float,
    cell: float = STEM_CELL,
    floor: float = STEM_FLOOR,
    step: float = STEM_BIN,
    occupancy: float = STEM_OCCUPANCY,
) -> tuple[np.ndarray, np.ndarray]:
    """Centres and heights of the columns: connected groups of cells whose points fill the height.

    A cell (``cell`` m, global grid) is a column cell when its highest point is at least
    ``min_height`` and its points above ``floor`` fall in at least ``occupancy`` of the
    ``step`` m height bins from ``floor`` to that point: a lattice's body, a pole, a trunk under
    its crown; not a crossarm, a conductor or a roof, whose points lie in a bin or two.

    Returns
    -------
    centers, heights
        ``(C, 2)`` float64 centres (the mean of each 8-connected group's cell centres) and ``(C,)``
        the highest point of each group (m above ground).
    """
    from scipy import ndimage

    hag = np.asarray(hag, np.float64)
    up = hag >= floor
    empty = (np.empty((0, 2)), np.empty(0))
    if not (up & (hag >= min_height)).any():
        return empty
    ix = np.floor(np.asarray(x)[up] / cell).astype(np.int64)
    iy = np.floor(np.asarray(y)[up] / cell).astype(np.int64)
    hb = np.floor((hag[up] - floor) / step).astype(np.int64)
    ox, oy = int(ix.min()), int(iy.min())
    nx, ny = int(ix.max()) - ox + 1, int(iy.max()) - oy + 1
    flat = (ix - ox) * ny + (iy - oy)
    top = np.full(nx * ny, -np.inf)
    np.maximum.at(top, flat, hag[up])
    bins = np.unique(flat * (int(hb.max()) + 1) + hb) // (int(hb.max()) + 1)  # one per occupied (cell, bin)
    filled = np.bincount(bins, minlength=nx * ny)
    spans = np.floor((np.maximum(top, floor) - floor) / step) + 1
    col = ((filled / spans >= occupancy) & (top >= min_height)).reshape(nx, ny)
    lab, n = ndimage.label(col, structure=np.ones((3, 3), bool))
    if n == 0:
        return empty
    groups = np.arange(1, n + 1)
    centres = np.asarray(ndimage.center_of_mass(col, lab, groups), np.float64).reshape(-1, 2)
    tops = np.asarray(ndimage.maximum(top.reshape(nx, ny), lab, groups), np.float64).reshape(-1)
    return (centres + [ox, oy] + 0.5) * cell, tops


def candidate_windows(
    x: np.ndarray,
    y: np.ndarray,
    hag: np.ndarray,
    core: np.ndarray,
    *,
    window: float = 40.0,
    min_height: float = 10.0,
    radius: float = PEAK_RADIUS,
    min_points: int = 1,
    canonical_order: np.ndarray | None = None,
    exclude: np.ndarray | None = None,
    tree: Any = None,
    secondary_radius: float = 0.0,
    secondary_reach: float = 0.0,
    stem_gap: float = 0.0,
    stem_reach: float = 0.0,
) -> CandidateWindows:
    """Windows centred on the height peaks of a tile that hold a core point (see the module docstring).

    Parameters
    ----------
    x, y, hag
        Coordinates and heights above ground of the tile's model-input points (core and buffer).
    core
        Bool mask: the point is owned by the tile.
    window
        Window side (m).
    min_height
        Peaks lower than this are not candidates (no tower is lower).
    radius
        A peak is the highest point within this distance (m).
    min_points
        Windows with fewer points are skipped.
    canonical_order
        A permutation giving the points' canonical order (see :func:`towerpipe.inference.windows.sliding_windows`).
    exclude
        Bool mask of points that make no peak (still in the windows): overhead wires, which
        pass over or beside a tower as high as its top and would hide its peak.
    tree
        A ``scipy.spatial.cKDTree`` of ``(x, y)`` (built here if not given; the inference
        shares one with the shape gate).
    secondary_radius, secondary_reach
        With ``0 < secondary_radius < radius``, the peaks within ``secondary_radius`` that are not
        peaks within ``radius`` (a tower among higher crowns) are candidates too, with a
        :attr:`CandidateWindows.reach` of ``secondary_reach``; 0: none.
    stem_gap, stem_reach
        With ``stem_gap`` > 0, the columns (:func:`stem_columns`) farther than ``stem_gap`` from
        every peak are candidates too (:attr:`CandidateWindows.stem`), with a reach of
        ``stem_reach``; 0: none.
    """
    from scipy.spatial import cKDTree

    from towerpipe.towers.kdtree import tile_tree

    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    core = np.asarray(core, dtype=bool)
    peak_pts = np.ones(len(x), bool) if exclude is None else ~np.asarray(exclude, dtype=bool)
    keys, centers, heights = height_peaks(
        x[peak_pts], y[peak_pts], np.asarray(hag)[peak_pts], min_height=min_height, radius=radius
    )
    reach = np.full(len(keys), np.inf)
    if 0 < secondary_radius < radius:
        if not secondary_reach > 0:
            raise ValueError(f"secondary_reach must be > 0 with secondary peaks, got {secondary_reach}")
        k2, c2, h2 = height_peaks(
            x[peak_pts], y[peak_pts], np.asarray(hag)[peak_pts], min_height=min_height, radius=secondary_radius
        )
        new = ~(k2[:, None, :] == keys[None, :, :]).all(-1).any(1) if len(keys) else np.ones(len(k2), bool)
        keys = np.concatenate([keys, k2[new]])
        centers = np.concatenate([centers, c2[new]])
        heights = np.concatenate([heights, h2[new]])
        reach = np.concatenate([reach, np.full(int(new.sum()), float(secondary_reach))])
    stem = np.zeros(len(keys), bool)
    if stem_gap > 0:
        if not stem_reach > 0:
            raise ValueError(f"stem_reach must be > 0 with stem candidates, got {stem_reach}")
        cols, tops = stem_columns(x[peak_pts], y[peak_pts], np.asarray(hag)[peak_pts], min_height=min_height)
        if len(cols) and len(centers):
            apart = cKDTree(centers).query(cols)[0] > stem_gap
            cols, tops = cols[apart], tops[apart]
        keys = np.concatenate([keys, np.floor(cols / PEAK_RES).astype(np.int64)])
        centers = np.concatenate([centers, cols])
        heights = np.concatenate([heights, tops])
        reach = np.concatenate([reach, np.full(len(cols), float(stem_reach))])
        stem = np.concatenate([stem, np.ones(len(cols), bool)])
    n = len(x)
    order = np.arange(n) if canonical_order is None else np.asarray(canonical_order)
    rank = None
    if not np.array_equal(order, np.arange(n)):
        rank = np.empty(n, np.int64)
        rank[order] = np.arange(n)
    if tree is None and len(keys):
        tree = tile_tree(np.c_[x, y])
    half = window / 2.0
    counts = core_counts = np.zeros(len(keys), np.int64)
    if len(keys) and n:
        counts = np.asarray(tree.query_ball_point(centers, half, p=np.inf, return_length=True), np.int64)
        # the core points of a window: its points less those of the buffer (a tree of the buffer's
        # points is a fraction of a tree of the core's)
        core_counts = counts.copy()
        if not core.all():
            buffer_tree = tile_tree(np.c_[x[~core], y[~core]])
            core_counts -= np.asarray(
                buffer_tree.query_ball_point(centers, half, p=np.inf, return_length=True), np.int64
            )
    keep = np.flatnonzero((counts >= max(int(min_points), 1)) & (core_counts > 0))
    return CandidateWindows(
        float(window),
        keys[keep],
        centers[keep],
        heights[keep],
        counts[keep],
        core_counts[keep],
        reach[keep],
        stem[keep],
        _WindowPoints(tree, rank),
    )


def segmented_windows(centers: np.ndarray, reach: np.ndarray, passed: np.ndarray) -> np.ndarray:
    """The peak windows the segmenter reads: those of ``passed`` (indices of the windows that
    passed the gates) but a secondary peak's within :data:`PEAK_RADIUS` of a segmented primary
    peak (mostly another top of that tower, a shield-wire peak or a crossarm's end, whose window
    would paint the crowns around it: the segmenter reads a window's centre as the tower's place).
    Where every window passed is secondary, all are read. ``centers``, ``reach``: every window's."""
    passed = np.asarray(passed, np.int64)
    sec = np.isfinite(reach[passed])
    if not sec.any() or sec.all():
        return passed
    prim = centers[passed[~sec]]
    d = np.hypot(*(centers[passed[sec]][:, None, :] - prim[None, :, :]).transpose(2, 0, 1)).min(1)
    return np.sort(np.concatenate([passed[~sec], passed[sec][d > PEAK_RADIUS]]))


def stems_beside(stems: np.ndarray, painted: np.ndarray) -> np.ndarray:
    """Bool mask of the stem windows (centres ``stems``, ``(S, 2)``) beside a painted tower: at least
    :data:`STEM_PAINTED` points of ``painted`` (``(P, 2)`` x, y of the points the peak windows
    painted) within :data:`PEAK_RADIUS`."""
    from scipy.spatial import cKDTree

    stems = np.asarray(stems, np.float64).reshape(-1, 2)
    if not len(stems) or not len(painted):
        return np.zeros(len(stems), bool)
    n = cKDTree(np.asarray(painted, np.float64)).query_ball_point(stems, PEAK_RADIUS, return_length=True)
    return np.asarray(n) >= STEM_PAINTED[0]
