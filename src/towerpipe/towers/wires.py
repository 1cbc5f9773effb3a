"""Conductor support: do overhead wires leave a tower candidate toward the next tower?

A transmission tower carries conductors that run in straight lines (in plan) to the
next tower, 100-500 m away. Tower cranes, lattice telecom masts, chimneys and wind
turbines can look like a tower inside a 40 m window, but nothing hangs from them that
continues for a hundred metres. :func:`wire_support` measures that, from the tile's
points around a candidate, with no model:

1. **Wire points** (:func:`wire_points`): points at least ``min_hag`` above ground
   that are sparse in plan (at most ``max_neighbours`` points within ``radius`` m),
   with air above and below them (no neighbour there between ``max_dz`` and
   ``min_gap`` m higher or lower: a crown has points at every height, while stacked
   conductors are several metres apart), and whose 3-D neighbourhood (``line_radius`` m)
   is a nearly horizontal line (linearity ``(l1 - l2) / l1 >= min_linearity``).
2. **Pointing at the candidate**: a wire point counts when the straight line through
   it, along its local direction, passes within ``max_offset`` m of the candidate's
   centre (conductors hang from crossarms at most ~12 m from the tower axis). A line
   passing by, or the jib of a crane, does not.
3. **Reach**: in each angular sector (``sector`` degrees wide, every 5 degrees), the
   share of the radial bins (``step`` m) between ``r_min`` and ``r_max`` that hold
   such a point. The support is the best sector's share: 1.0 means a conductor runs
   out of the candidate over the whole ring, 0.0 that nothing does.

Radial bins outside the data are left out of a sector's share: "the data" is where
points exist (:class:`~towerpipe.towers.coverage.Coverage`: 10 m cells holding any point of the tile, ground
included), not the tile's box, so a tower in a corridor strip a few tens of metres wide,
or at the edge of a survey, is not scored on the empty land beside it. A sector needs
``min_bins`` bins in the data, and where no sector has them the support is ``nan``
(unknown: a candidate is never dropped for lack of data; the QA flags it).

On the `calib` zone, with the defaults, all 17 true towers score 1.0 and the cranes,
masts, chimneys and turbines at most 0.38 (see ``towers.min_wire_support``).

:func:`tile_conductor_points` keeps the wire points of a tile's core with the clearance to
the vegetation below each (each inference job writes its tile's, :mod:`towerpipe.io.conductors`;
:func:`conductor_points` gathers a block's): the zone links its towers into lines and
measures the spans from them (:mod:`towerpipe.towers.lines`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse

from towerpipe import classes
from towerpipe.io.conductors import CONDUCTOR_ARRAYS
from towerpipe.io.fields import Field
from towerpipe.towers.clearance import wire_clearance
from towerpipe.towers.coverage import Coverage
from towerpipe.towers.kdtree import tile_tree

__all__ = [
    "wire_points",
    "wire_support",
    "aimed_wire_points",
    "conductor_heights",
    "conductor_directions",
    "tile_conductor_points",
    "conductor_points",
    "CONDUCTOR_FIELDS",
]


#: The defaults of the ring the conductors are looked for in (m, from the candidate), of the aim (m:
#: a wire counts when its line passes this close to the candidate) and of a wire point's height
#: floor (m above ground): :func:`wire_support`, :func:`conductor_heights`, :func:`tile_conductor_points`.
RING_MIN_M, RING_MAX_M, AIM_M, WIRE_MIN_HAG_M = 80.0, 160.0, 12.0, 5.0


#: Fields of a conductor point (layer ``conductor_points`` of a block's GeoPackage; Point geometry).
CONDUCTOR_FIELDS: dict[str, Field] = {
    "block": Field("str", "Block", "Block of the point"),
    "z": Field("float64", "Elevation (m)", "Elevation of the point (m)", 2),
    "hag": Field("float64", "Height above ground (m)", "Height of the point above the ground (m)", 2),
    "direction_deg": Field(
        "float64",
        "Wire direction (°)",
        "Axis of the wire through the point, degrees clockwise from grid north (0-180)",
        1,
    ),
    "clearance_m": Field(
        "float64",
        "Clearance (m)",
        "Vertical distance down to the highest vegetation point "
        "(classes 3-5) within 2 m in plan below it; NULL when "
        "there is none",
        2,
    ),
}


def wire_points(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    *,
    radius: float = 1.0,
    max_neighbours: int = 20,
    max_dz: float = 1.0,
    min_gap: float = 2.5,
    line_radius: float = 2.5,
    min_linearity: float = 0.9,
    judge: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Which points look like overhead wire, and the plan direction of their wire.

    Parameters
    ----------
    x, y, z
        Coordinates (m) of candidate points (already above the height floor).
    judge
        ``(n,)`` bool, the points to judge (default all; the others are neighbours only):
        a judged point gets the answer it gets when all are judged.
    radius, max_neighbours, max_dz, min_gap
        Plan neighbourhood: at most ``max_neighbours`` points (the point included)
        within ``radius`` m, none of them between ``max_dz`` and ``min_gap`` m above or
        below the point (a crown has points at every height; conductors stacked one
        above the other are at least ``min_gap`` apart).
    line_radius, min_linearity
        3-D neighbourhood of the surviving points and the linearity it needs.

    Returns
    -------
    mask
        ``(n,)`` bool.
    direction
        ``(n, 2)`` unit plan direction of the local line (zeros where not a wire point).
    """
    x, y, z = (np.asarray(a, dtype=np.float64) for a in (x, y, z))
    n = len(x)
    mask = np.zeros(n, dtype=bool)
    direction = np.zeros((n, 2))
    if n < 3:
        return mask, direction
    xy = np.c_[x, y]
    tree = tile_tree(xy)
    ok = np.zeros(n, dtype=bool)
    # most points of a crown have another point straight above or below them in the gap: they are
    # left out before the (costlier) counting, which would not make them wire points either
    judge = ~_stacked(x, y, z, radius, max_dz, min_gap) & (True if judge is None else np.asarray(judge, bool))
    judged = np.flatnonzero(judge)
    ok[judged[tree.query_ball_point(xy[judged], radius, return_length=True) <= max_neighbours]] = True
    # a sparse point with a neighbour between max_dz and min_gap above or below is in a crown;
    # only the sparse points' neighbourhoods are looked at (in a forest most points are dense:
    # the pairs of all points would be ~15 per point)
    sparse_idx = np.flatnonzero(ok)
    if len(sparse_idx):
        near = tile_tree(xy[sparse_idx]).sparse_distance_matrix(tree, radius, output_type="coo_matrix")
        rows, cols = sparse_idx[near.row], near.col
        dz = np.abs(z[rows] - z[cols])
        ok[rows[(dz >= max_dz) & (dz < min_gap)]] = False
    cand = np.flatnonzero(ok)
    if len(cand) == 0:
        return mask, direction
    # local covariance of each candidate over *all* points within line_radius (3-D), so a
    # sparse point at the edge of a crown is judged with the crown around it
    p = np.c_[x, y, z]
    p -= p.mean(axis=0)
    near = tile_tree(p[cand]).sparse_distance_matrix(tile_tree(p), line_radius, output_type="coo_matrix")
    m = len(cand)
    # the point itself is added: a distance of 0 is not stored in the sparse result
    rows, cols = np.r_[near.row, np.arange(m)], np.r_[near.col, cand]
    adj = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, n))
    adj.sum_duplicates()
    adj.data[:] = 1.0  # a point listed twice counts once
    k = np.asarray(adj.sum(axis=1)).ravel()
    mean = (adj @ p) / k[:, None]
    second = np.stack([adj @ (p[:, i] * p[:, j]) for i in range(3) for j in range(3)], axis=1).reshape(m, 3, 3)
    cov = second / k[:, None, None] - mean[:, :, None] * mean[:, None, :]
    ev, vec = np.linalg.eigh(cov)
    lin = (ev[:, 2] - ev[:, 1]) / np.maximum(ev[:, 2], 1e-12)
    axis = vec[:, :2, 2]
    flat = np.hypot(axis[:, 0], axis[:, 1])
    good = (k >= 3) & (lin >= min_linearity) & (flat >= 0.9)
    mask[cand[good]] = True
    direction[cand[good]] = axis[good] / flat[good, None]
    return mask, direction


def _stacked(x: np.ndarray, y: np.ndarray, z: np.ndarray, radius: float, lo: float, hi: float) -> np.ndarray:
    """Bool mask: the points with another point at least ``lo`` and less than ``hi`` m above or
    below them in the same plan cell, a cell small enough (side ``radius / sqrt(2)``, a little
    less) that the two are within ``radius`` of each other in plan.

    Every point marked fails :func:`wire_points`' test of the air above and below (it is found
    among the point's neighbours there); a point not marked may still fail it. Neighbours at a
    height difference within a rounding margin of ``lo`` or ``hi`` are not taken: that test
    decides them.
    """
    cell = 0.999 * radius / np.sqrt(2.0)
    ix = np.floor((x - x.min()) / cell).astype(np.int64)
    iy = np.floor((y - y.min()) / cell).astype(np.int64)
    key = ix * (int(iy.max()) + 1) + iy
    # one sorted axis: a cell's points by height, the cells far apart (more than ``hi``); sorted
    # once as floats (a lexical sort of cell and height took twice as long; points of equal value
    # get the same answer whatever their order)
    span = float(z.max() - z.min()) + 2.0 * hi + 1.0
    v = key * span + (z - z.min())
    order = np.argsort(v)
    v = v[order]
    margin = max(64.0 * float(np.spacing(np.abs(v).max())), 1e-9)
    above = np.searchsorted(v, v + hi - margin, "right") > np.searchsorted(v, v + lo + margin, "left")
    below = np.searchsorted(v, v - lo - margin, "right") > np.searchsorted(v, v - hi + margin, "left")
    out = np.zeros(len(x), dtype=bool)
    out[order] = above | below
    return out


def wire_support(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    hag: np.ndarray,
    cx: float,
    cy: float,
    *,
    extent: Sequence[float] | Coverage | None = None,
    r_min: float = RING_MIN_M,
    r_max: float = RING_MAX_M,
    step: float = 10.0,
    sector: float = 20.0,
    max_offset: float = AIM_M,
    min_hag: float = WIRE_MIN_HAG_M,
    min_bins: int = 4,
    min_ring_coverage: float = 0.0,
    return_heights: bool = False,
    directions: np.ndarray | None = None,
) -> float | tuple[float, np.ndarray]:
    """Share of the ring ``[r_min, r_max)`` m around ``(cx, cy)`` reached by a conductor.

    Parameters
    ----------
    x, y, z, hag
        The points around the candidate (a tile's model-input points: no ground).
    cx, cy
        Candidate centre (the tower's footprint centroid).
    extent
        Where data exists: a :class:`~towerpipe.towers.coverage.Coverage`, or ``(xmin, ymin, xmax, ymax)``; radial
        bins whose centre lies outside are not counted. ``None``: everything is covered.
    r_min, r_max, step
        The ring and its radial bins (m). ``r_min`` is beyond a crane's jib (<= 80 m).
    sector
        Angular width of a sector (degrees); sectors start every 5 degrees.
    max_offset
        A wire point counts when its line passes this close (m) to the centre.
    min_hag
        Height floor (m) of wire points.
    min_bins
        Radial bins a sector needs inside ``extent`` to be scored.
    min_ring_coverage
        Share of the ring's bins (all sectors) that must lie in the data for the support
        to be known: below it, where the conductors go may be outside the data (a
        corridor strip crossing the line, the corner of a survey) and the support is
        ``nan``. 0 scores any ring with one scored sector. A :class:`~towerpipe.towers.coverage.Coverage` with a
        ``survey`` also leaves the support ``nan`` when fewer than its ``min_line_share``
        of the lines through the candidate show in the surveyed area (:meth:`~towerpipe.towers.coverage.Coverage.lines_seen`):
        a conductor may then leave the tower where no data is.
    return_heights
        Also return the heights above ground of the wire points counted (those
        :func:`conductor_heights` gives; empty when the support is ``nan``), from the same search.
    directions
        ``(n, 2)`` plan directions of the given points' wires when the points are wire points
        already judged (:func:`tile_conductor_points`, each among all the points of its tile): the
        ring's points are then not judged again. ``None``: the points are any points, and those of
        the ring are judged among themselves (:func:`wire_points`).

    Returns
    -------
    float
        The best sector's share of bins holding a wire point that points at the
        candidate, in ``[0, 1]``; ``nan`` when no sector has ``min_bins`` bins in the data.
    numpy.ndarray
        With ``return_heights``: float64 heights (m), one per wire point counted.
    """

    def out(support: float, idx: np.ndarray) -> float | tuple[float, np.ndarray]:
        return (support, np.asarray(hag, dtype=np.float64)[idx]) if return_heights else support

    none = np.zeros(0, dtype=np.int64)
    nbins = int(round((r_max - r_min) / step))
    starts = np.arange(0.0, 360.0, 5.0)
    # bins of each sector inside the data: test the bin centres on the sector's mid ray
    mid = np.radians(starts + sector / 2.0)
    rc = r_min + step * (np.arange(nbins) + 0.5)
    bx = cx + np.cos(mid)[:, None] * rc[None, :]
    by = cy + np.sin(mid)[:, None] * rc[None, :]
    if extent is None:
        inside = np.ones((len(starts), nbins), dtype=bool)
    elif isinstance(extent, Coverage):
        inside = extent.contains(bx, by)
        if extent.survey and extent.lines_seen(bx, by, min_bins) < extent.min_line_share:
            return out(float("nan"), none)
    else:
        xmin, ymin, xmax, ymax = extent
        inside = (bx >= xmin) & (bx < xmax) & (by >= ymin) & (by < ymax)
    avail = inside.sum(axis=1)
    scored = avail >= min_bins
    if not scored.any() or inside.mean() < min_ring_coverage:
        return out(float("nan"), none)
    idx, px, py, _ = aimed_wire_points(x, y, z, hag, cx, cy, r_min, r_max, min_hag, max_offset, directions)
    if len(px) == 0:
        return out(0.0, idx)
    ang = np.degrees(np.arctan2(py, px)) % 360.0
    rb = np.minimum(((np.hypot(px, py) - r_min) // step).astype(np.int64), nbins - 1)
    hit = np.zeros((len(starts), nbins), dtype=bool)
    for s, a0 in enumerate(starts):
        in_sector = ((ang - a0) % 360.0) < sector
        hit[s, rb[in_sector]] = True
    share = (hit & inside).sum(axis=1) / np.maximum(avail, 1)
    return out(float(share[scored].max()), idx)


def aimed_wire_points(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    hag: np.ndarray,
    cx: float,
    cy: float,
    r_min: float,
    r_max: float,
    min_hag: float,
    max_offset: float,
    directions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The wire points in the ring ``[r_min, r_max)`` m around ``(cx, cy)``, at least ``min_hag``
    high (judged among themselves by :func:`wire_points`, or already judged: ``directions``),
    whose wire passes within ``max_offset`` m of it: their indices, their offsets
    ``(x - cx, y - cy)`` and their wires' ``(n, 2)`` plan directions."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    dx, dy = x - cx, y - cy
    d = np.hypot(dx, dy)
    idx = np.flatnonzero((d >= r_min) & (d < r_max) & (np.asarray(hag) >= min_hag))
    if directions is None:
        wire, u = wire_points(x[idx], y[idx], np.asarray(z, dtype=np.float64)[idx])
        idx, u = idx[wire], u[wire]
    else:
        u = np.asarray(directions, dtype=np.float64)[idx]
    aimed = np.abs(dx[idx] * u[:, 1] - dy[idx] * u[:, 0]) <= max_offset
    idx, u = idx[aimed], u[aimed]
    return idx, dx[idx], dy[idx], u


def conductor_heights(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    hag: np.ndarray,
    cx: float,
    cy: float,
    *,
    r_min: float = RING_MIN_M,
    r_max: float = RING_MAX_M,
    max_offset: float = AIM_M,
    min_hag: float = WIRE_MIN_HAG_M,
    directions: np.ndarray | None = None,
) -> np.ndarray:
    """Heights above ground (m) of the wire points that :func:`wire_support` counts for ``(cx, cy)``:
    in the ring ``[r_min, r_max)`` m, at least ``min_hag`` high, their wire passing within
    ``max_offset`` m of it (the same defaults).

    A tower carries its conductors at its top and they sag toward the next tower, so these lie
    well below a tower's top; a crown under a line stays below them (rule 12 of
    :func:`towerpipe.towers.extract.extract_towers`, ``towers.vouch_height``).

    Returns
    -------
    numpy.ndarray
        float64, one value per such point (empty when there is none).
    """
    idx, _, _, _ = aimed_wire_points(x, y, z, hag, cx, cy, r_min, r_max, min_hag, max_offset, directions)
    return np.asarray(hag, dtype=np.float64)[idx]


def conductor_directions(direction_deg: np.ndarray) -> np.ndarray:
    """``(n, 2)`` unit plan directions ``(dx, dy)`` of wires given as bearings in degrees
    (``direction_deg`` of :func:`tile_conductor_points`: clockwise from north, in [0, 180))."""
    a = np.radians(np.asarray(direction_deg, dtype=np.float64))
    return np.column_stack([np.sin(a), np.cos(a)])


#: Columns of a tile's model input that :func:`tile_conductor_points` reads.
CONDUCTOR_INPUT_COLUMNS: tuple[str, ...] = ("x", "y", "z", "hag", "classification", "core", "model_input")


def tile_conductor_points(
    tile: dict[str, np.ndarray], *, min_hag: float = WIRE_MIN_HAG_M, clearance_radius: float = 2.0
) -> dict[str, np.ndarray]:
    """The wire points of one tile's core, with their wire's direction and their clearance.

    The tile's core model-input points at least ``min_hag`` above the ground are judged by
    :func:`wire_points` among those of core and buffer (a point at the core's edge has its
    neighbours): over the tiles of a block each point is judged once. A point's clearance:
    its height above the highest vegetation below it within ``clearance_radius`` m (nan: none).

    Parameters
    ----------
    tile
        The tile's arrays (at least :data:`CONDUCTOR_INPUT_COLUMNS`, as
        :func:`towerpipe.io.tiles.load_tile` gives them).
    min_hag
        Height floor (m) of a wire point.
    clearance_radius
        Plan radius (m) in which the vegetation below a wire point is looked for.

    Returns
    -------
    dict
        :data:`CONDUCTOR_ARRAYS` (float64): ``x, y, z, hag, direction_deg, clearance_m``,
        as in :data:`CONDUCTOR_FIELDS`.
    """
    t = tile
    inp = np.asarray(t["model_input"], dtype=bool)
    high = np.flatnonzero(inp & (t["hag"] >= min_hag))
    core = np.asarray(t["core"], dtype=bool)[high]
    wire, direction = wire_points(t["x"][high], t["y"][high], t["z"][high], judge=core)
    keep = wire & core
    idx = high[keep]
    veg = np.flatnonzero(inp & np.isin(t["classification"], classes.VEGETATION))
    veg = np.setdiff1d(veg, high[wire], assume_unique=True)
    u = direction[keep]
    x, y, z = (np.asarray(t[k], dtype=np.float64) for k in ("x", "y", "z"))
    out = {
        "x": x[idx],
        "y": y[idx],
        "z": z[idx],
        "hag": t["hag"][idx],
        "direction_deg": np.degrees(np.arctan2(u[:, 0], u[:, 1])) % 180.0,
        "clearance_m": wire_clearance(x[idx], y[idx], z[idx], x[veg], y[veg], z[veg], clearance_radius),
    }
    return {k: np.asarray(out[k], dtype=np.float64) for k in CONDUCTOR_ARRAYS}


def conductor_points(tile_paths: Sequence[str], block: str, **kw: float) -> dict[str, np.ndarray]:
    """The wire points of a block, from its tile files (:func:`tile_conductor_points` of each).

    Parameters
    ----------
    tile_paths
        Tile files; those of other blocks (``meta["block"]``) are skipped.
    block
        The block.
    **kw
        ``min_hag``, ``clearance_radius`` of :func:`tile_conductor_points`.

    Returns
    -------
    dict
        :data:`CONDUCTOR_ARRAYS` (float64), the tiles' points one after the other.
    """
    from towerpipe.io.columns import read_meta
    from towerpipe.io.tiles import load_tile

    parts = [
        tile_conductor_points(load_tile(p, columns=list(CONDUCTOR_INPUT_COLUMNS)).arrays, **kw)
        for p in tile_paths
        if read_meta(p).get("block") == block
    ]
    return {k: np.concatenate([q[k] for q in parts]) if parts else np.empty(0) for k in CONDUCTOR_ARRAYS}
