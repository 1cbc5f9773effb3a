"""A cluster's plan: where it stands (:func:`base`), a crane's jib (rule 15 of
:func:`towerpipe.towers.extract.extract_towers`), and whether anything in it stands (rule 16).

A tower crane's cluster is its mast and the part of its jib the segmenter paints: in plan a narrow
line (the jib is about 1.5-2.5 m wide) reaching 10-60 m out from the mast on one side. A
transmission tower's crossarms reach at most about 12 m from its body
(:data:`~towerpipe.towers.wires.AIM_M`), and a lattice tower that tall is wider than
:data:`JIB_MAX_WIDTH_M` at its base. :func:`arm_reach` measures both from the cluster's points; the
rule drops a cluster at least ``towers.wire_min_height`` high whose plan is at most
:data:`JIB_MAX_WIDTH_M` wide and whose upper half reaches ``towers.max_arm_reach`` m or more from its
base, and the rescue (rule 10) leaves such a crane's points alone (docs/model.md, "The conductors'
sides and a crane's jib").

A piece of conductor the segmenter paints (in a delivery that classifies no wire, where the wire
detector missed it) hangs along a line: over each spot of its plan its points lie at one height.
Anything that stands (a tower's body or legs, a pole, a crown) has points metres apart in height over
some spot. :func:`tallest_stand` measures it; rule 16 drops a cluster whose tallest stand is under
``towers.min_stand`` (docs/model.md, "A delivery without a wire class").
"""

from __future__ import annotations

import numpy as np

__all__ = ["JIB_MAX_WIDTH_M", "STAND_CELL_M", "arm_reach", "base", "tallest_stand"]

#: A plan at most this wide (m, across its long axis) may be a crane's jib and mast.
JIB_MAX_WIDTH_M = 3.0
#: Plan cell (m) over which :func:`tallest_stand` reads a height range.
STAND_CELL_M = 1.0
#: The ends of a plan are read at these percentiles of the points (a stray point does not set them).
_ENDS = (2.0, 98.0)


def base(xy: np.ndarray, hag: np.ndarray) -> np.ndarray:
    """Where a cluster stands: the median (x, y) of its lowest third (of its height range). A
    crane's footprint centroid lies out along its jib, its base is its mast.

    Parameters
    ----------
    xy
        (n, 2) plan coordinates of the cluster's points.
    hag
        (n,) their heights above ground.
    """
    low = hag <= hag.min() + (hag.max() - hag.min()) / 3.0
    return np.median(xy[low], axis=0)


def arm_reach(xy: np.ndarray, hag: np.ndarray, base: tuple[float, float]) -> tuple[float, float]:
    """How far a cluster's upper half reaches from its base, and how wide its plan is.

    Parameters
    ----------
    xy
        ``(n, 2)`` plan coordinates of the cluster's points.
    hag
        ``(n,)`` their heights above ground.
    base
        The cluster's base (the median plan position of its lowest third).

    Returns
    -------
    reach : float
        The farther of the two ends (m, 2nd and 98th percentile) of the points at or above half its
        height, along their long axis, from the base.
    width : float
        The extent (m, 2nd to 98th percentile) of all its points across that axis.
        Both are 0 with fewer than 3 points in the upper half.
    """
    xy = np.asarray(xy, dtype=np.float64) - np.asarray(base, dtype=np.float64)
    hag = np.asarray(hag, dtype=np.float64)
    top = xy[hag >= 0.5 * hag.max()] if len(hag) else xy
    if len(top) < 3:
        return 0.0, 0.0
    axes = np.linalg.eigh(np.cov(top.T))[1]  # columns: the short axis, then the long one
    along = np.percentile(top @ axes[:, 1], _ENDS)
    across = np.percentile(xy @ axes[:, 0], _ENDS)
    return float(max(along[1], -along[0])), float(across[1] - across[0])


def tallest_stand(xyz: np.ndarray, cell: float = STAND_CELL_M) -> float:
    """The largest height range (m) of a cluster's points over one plan cell of ``cell`` m.

    Parameters
    ----------
    xyz
        ``(n, 3)`` coordinates of the cluster's points (m; float64, any plan offset).
    cell
        Side (m) of the plan cells, on a grid from the origin.

    Returns
    -------
    float
        0 for no point.
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if not len(xyz):
        return 0.0
    _, cells = np.unique(np.floor(xyz[:, :2] / cell).astype(np.int64), axis=0, return_inverse=True)
    cells = cells.ravel()
    top = np.full(cells.max() + 1, -np.inf)
    low = np.full(cells.max() + 1, np.inf)
    np.maximum.at(top, cells, xyz[:, 2])
    np.minimum.at(low, cells, xyz[:, 2])
    return float((top - low).max())
