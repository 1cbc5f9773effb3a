"""What a cluster's conductors say about it: the tower rules of
:func:`towerpipe.towers.extract.extract_towers` that read the wires around a cluster.

- **Support** (rule 7, :func:`support`): the share of the 80-160 m ring reached by a conductor
  pointing at the cluster's base (:func:`towerpipe.towers.wires.wire_support`).
- **Vouch** (rule 12, :func:`vouching_support`): conductors pointing at a cluster the shape check
  drops, its top well above them, keep it; a few metres above them do for a cluster that scores
  almost as a tower (:func:`needed_vouch_height`): a small tower carries its conductors close under
  its top.
- **Sides** (rule 14, :func:`conductor_balance`): a tower carries its conductors on both sides of
  its body, or over it; a crane, a mast or a tree *beside* a line has every conductor pointing at
  it on one side. The balance is the share of the conductor points counted by the support that lie
  on the less-held side of the base, or within :data:`OVER_M` of it. A tower's is about 0.5 (0.16
  or more on the twelve calibration zones); a crane's or a tree's beside a line 0-0.15. The rule
  asks it only of a cluster whose shape is in doubt: a tower strung on one side only has its
  conductors on one side too (docs/model.md, "The conductors' sides and a crane's jib"). An
  unknown balance (too few points) drops only a cluster that the vouch keeps.
- **Near** (rule 19, :func:`near_balance`): where the support cannot decide, the conductors nearer
  than its ring do. Unknown (the 80-160 m ring lies outside the data: a small tile, the edge of a
  survey): a tower's own conductors hang from it, on both sides or over it, while a crane or a tree
  beside a line has the line's conductors on one side, or none pointing at it at all. Under
  ``min_wire_support`` (a sparse flight, whose far conductors the detector barely finds): conductors
  hanging on both sides of a cluster or over it keep it.
- **On a conductor's line** (rule 17, :func:`line_share`): the share of a cluster's points that lie
  on the line of a conductor the wire detector found nearby. The detector misses the ends of the
  wires it finds (where they thin, sag into a crown's reach, or cross another circuit); the
  segmenter paints some of those points, and where the delivery classifies no wire nothing else
  takes them away. A tower holds a conductor's line only at its crossarms' tips.
- **Under a line** (rule 20, :func:`under_line`): a tower carries its own conductors, at or below its
  top; a crown under a line has the line's conductors only over it (the line's clearance over the
  vegetation), none at or below its top.
- **Bare** (rule 18, :func:`bare_score`): the shape score of a cluster's object without its points on
  those lines. Conductors over a crown make it look like a tower to the verifier (a body, and arms
  at the top); without them a crown scores near 0 and a tower keeps its score.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from towerpipe.config import TowersConfig
from towerpipe.towers.wires import AIM_M, RING_MAX_M, RING_MIN_M, WIRE_MIN_HAG_M, aimed_wire_points, wire_support

__all__ = [
    "BALANCE_MIN_POINTS",
    "BARE_MIN_POINTS",
    "LINE_ACROSS_M",
    "LINE_DZ_M",
    "LINE_REACH_M",
    "NEAR_AIMED_SHARE",
    "OVER_M",
    "bare_score",
    "conductor_balance",
    "line_share",
    "near_balance",
    "needed_vouch_height",
    "on_conductor_lines",
    "UNDER_LINE_CLEARANCE_M",
    "UNDER_LINE_GAP_M",
    "CANOPY_PERCENTILE",
    "CANOPY_RING_M",
    "UNDER_LINE_RADIUS_M",
    "canopy_clearance",
    "support",
    "under_line",
    "vouching_support",
]

#: A conductor point this close (m, across its wire) to the base is over the body (a shield wire, a
#: conductor of a central crossarm): it counts on both sides.
OVER_M = 1.0
#: The balance is known from this many counted conductor points on (fewer: unknown, ``nan``; a
#: cluster is never dropped for it).
BALANCE_MIN_POINTS = 20
#: A point is on a conductor's line (rule 17) when a conductor point within :data:`LINE_REACH_M` m of it
#: in plan has its wire pass within :data:`LINE_ACROSS_M` m of it in plan, and is within
#: :data:`LINE_DZ_M` m of its height.
LINE_REACH_M, LINE_ACROSS_M, LINE_DZ_M = 8.0, 0.5, 0.7
#: Rule 19: with fewer than :data:`BALANCE_MIN_POINTS` conductor points pointing at a base, and fewer
#: than this share of the conductor points near it, none points at it (a balance of 0).
NEAR_AIMED_SHARE = 0.1
#: Rule 18 judges an object without its conductors only when this many of its points are left.
BARE_MIN_POINTS = 10
#: Rule 20 counts the conductor points within :data:`UNDER_LINE_RADIUS_M` m of a base (in plan) whose
#: wire points at it, and tells those more than :data:`UNDER_LINE_CLEARANCE_M` m over the top of its
#: object from the rest: a tower's own conductors hang at or below its top (its earth wire at it), a
#: crown under a line has the line's only over it, clear of it by more than :data:`UNDER_LINE_GAP_M` m
#: of empty height (docs/model.md, "Rule 20").
UNDER_LINE_RADIUS_M, UNDER_LINE_CLEARANCE_M, UNDER_LINE_GAP_M = 25.0, 2.0, 4.0
#: Rule 22 measures what stands around a base in this ring (m, in plan): beyond a tower's crossarms and
#: the crowns at its foot, within the canopy of the wood it stands in (docs/model.md, "Rule 22").
CANOPY_RING_M = (20.0, 40.0)
#: Rule 22 takes this percentile of the heights above ground in :data:`CANOPY_RING_M` as the canopy's top
#: (not its tallest tree).
CANOPY_PERCENTILE = 90.0


def _conductors(arr: Mapping[str, Any]) -> tuple[Mapping[str, Any], Any]:
    """The points to look for conductors in and their wires' directions: the context's judged
    conductor points (``arr["conductors"]``) when it has them, else all its points (``None``)."""
    c = arr.get("conductors")
    return (arr, None) if c is None else (c, c["direction"])


def support(arr: Mapping[str, Any], extent: Any, bx: float, by: float, **kw: Any) -> Any:
    """Rule 7: the conductor support at ``(bx, by)`` (:func:`towerpipe.towers.wires.wire_support`):
    from the context's conductor points (``arr["conductors"]``, each judged in its own tile) when
    it has them, else from its points, the ring's judged among themselves."""
    c, directions = _conductors(arr)
    return wire_support(c["x"], c["y"], c["z"], c["hag"], bx, by, extent=extent, directions=directions, **kw)


def needed_vouch_height(rules: TowersConfig, shape: float) -> float:
    """How far (m) rule 12 needs a cluster's top over its conductors, by its shape score ``shape``:
    ``vouch_low_height`` when it scores at least ``vouch_low_score`` (a small tower carries its
    conductors a few metres under its top), else ``vouch_height``; 0: rule 12 keeps nothing."""
    if rules.vouch_height <= 0:
        return 0.0
    if rules.vouch_low_height > 0 and shape >= rules.vouch_low_score:  # NaN (no object) is not
        return min(rules.vouch_height, rules.vouch_low_height)
    return rules.vouch_height


def vouching_support(
    rules: TowersConfig,
    arr: Mapping[str, np.ndarray],
    extent: Any,
    hag: np.ndarray,
    bx: float,
    by: float,
    shape: float = float("nan"),
) -> float | None:
    """Rule 12: the conductor support of a cluster the shape check dropped, when its conductors
    vouch for it (a known support of at least ``min_wire_support``, and its top ``hag.max()``
    :func:`needed_vouch_height` m or more above their median height in its ring,
    :func:`towerpipe.towers.wires.conductor_heights`, from the support's own search); else ``None``.
    ``(bx, by)``: its base; ``shape``: its shape score (NaN: none)."""
    needed = needed_vouch_height(rules, shape)
    if needed <= 0:
        return None
    found, heights = support(arr, extent, bx, by, return_heights=True)
    if not found >= rules.min_wire_support:  # NaN (unknown) never vouches
        return None
    if len(heights) == 0 or float(hag.max()) - float(np.median(heights)) < needed:
        return None
    return found


def conductor_balance(arr: Mapping[str, Any], bx: float, by: float) -> float:
    """Rule 14: how evenly the conductors pointing at a base ``(bx, by)`` lie on its two sides.

    The conductor points are those the support counts (in the 80-160 m ring, their wire passing
    within :data:`~towerpipe.towers.wires.AIM_M` of the base). Each one's side is the sign of its
    offset across its wire, the wires' directions oriented alike (along their main direction).

    Parameters
    ----------
    arr
        The context (``x``, ``y``, ``z``, ``hag`` and optionally ``conductors``, as :func:`support`
        reads it).
    bx, by
        The cluster's base.

    Returns
    -------
    float
        The share of the points on the side holding fewer, plus the share within :data:`OVER_M` of
        the base: 0 when all lie on one side, about 0.5 when the two sides hold as many; ``nan``
        with fewer than :data:`BALANCE_MIN_POINTS` points.
    """
    c, directions = _conductors(arr)
    args = (c["x"], c["y"], c["z"], c["hag"], bx, by, RING_MIN_M, RING_MAX_M, WIRE_MIN_HAG_M, AIM_M, directions)
    idx, px, py, u = aimed_wire_points(*args)
    if len(idx) < BALANCE_MIN_POINTS:
        return float("nan")
    return _balance(px, py, u)


def _balance(px: np.ndarray, py: np.ndarray, u: np.ndarray) -> float:
    """The balance of conductor points at offsets ``(px, py)`` from a base, their wires' plan
    directions ``u`` (:func:`conductor_balance`)."""
    main = np.linalg.eigh(u.T @ u)[1][:, -1]  # the wires' main direction; a wire's sign is arbitrary
    u = u * np.where(u @ main < 0, -1.0, 1.0)[:, None]
    across = px * u[:, 1] - py * u[:, 0]
    over = np.abs(across) <= OVER_M
    return float(min((across > OVER_M).mean(), (across < -OVER_M).mean()) + over.mean())


def near_balance(arr: Mapping[str, Any], bx: float, by: float, radius: float = RING_MIN_M) -> float:
    """Rule 19: the balance of the conductors nearer than the support's ring, for a base whose
    support cannot decide (unknown, or under ``min_wire_support``).

    The conductor points within ``radius`` m of the base ``(bx, by)`` (in plan; at least
    :data:`~towerpipe.towers.wires.WIRE_MIN_HAG_M` above ground) whose wire passes within
    :data:`~towerpipe.towers.wires.AIM_M` of it are those that point at it; their balance is
    :func:`conductor_balance`'s. With fewer than :data:`BALANCE_MIN_POINTS` of them it is 0 when
    they are also fewer than :data:`NEAR_AIMED_SHARE` of the conductor points within ``radius``
    (a line passes by, none of its wires points at it), else unknown.

    Returns
    -------
    float
        The balance (0-1); ``nan`` (unknown) with fewer than :data:`BALANCE_MIN_POINTS` conductor
        points within ``radius``, or too few pointing at it to say.
    """
    c, directions = _conductors(arr)
    near, px, py, u = aimed_wire_points(
        c["x"], c["y"], c["z"], c["hag"], bx, by, 0.0, radius, WIRE_MIN_HAG_M, np.inf, directions
    )
    if len(near) < BALANCE_MIN_POINTS:
        return float("nan")
    aimed = np.abs(px * u[:, 1] - py * u[:, 0]) <= AIM_M
    if aimed.sum() < BALANCE_MIN_POINTS:
        return 0.0 if aimed.sum() < NEAR_AIMED_SHARE * len(near) else float("nan")
    return _balance(px[aimed], py[aimed], u[aimed])


def under_line(arr: Mapping[str, Any], bx: float, by: float, top: float, obj: np.ndarray) -> tuple[int, int]:
    """Rule 20: the conductor points within :data:`UNDER_LINE_RADIUS_M` m of a base ``(bx, by)`` whose
    wire passes within :data:`~towerpipe.towers.wires.AIM_M` of it, against the top of its object.

    The top is the cluster's highest point ``top`` (an elevation), raised through the points of its
    object (the context's points ``obj``, as the shape check takes them) above it while no empty
    height of more than :data:`UNDER_LINE_GAP_M` m parts them: the whole of a tower, also where the
    segmenter painted only its lower part, but not a line passing over a crown, which stands clear of
    it.

    Returns
    -------
    over, under
        How many stand more than :data:`UNDER_LINE_CLEARANCE_M` m above that top, and how many do not.
    """
    c, directions = _conductors(arr)
    idx, _, _, _ = aimed_wire_points(
        c["x"], c["y"], c["z"], c["hag"], bx, by, 0.0, UNDER_LINE_RADIUS_M, WIRE_MIN_HAG_M, AIM_M, directions
    )
    zs = np.sort(np.asarray(arr["z"])[np.asarray(obj, np.int64)].astype(np.float64))
    zs = zs[zs > top]
    if len(zs):
        steps = np.diff(np.r_[top, zs])
        clear = np.flatnonzero(steps > UNDER_LINE_GAP_M)
        reach = clear[0] if len(clear) else len(zs)
        top = float(zs[reach - 1]) if reach else top
    over = int((np.asarray(c["z"])[idx] > top + UNDER_LINE_CLEARANCE_M).sum())
    return over, len(idx) - over


def canopy_clearance(arr: Mapping[str, Any], bx: float, by: float, height: float) -> float:
    """Rule 22: how far (m) a cluster whose highest point stands ``height`` m above the ground rises over
    what stands around its base ``(bx, by)``: over the :data:`CANOPY_PERCENTILE` th percentile of the
    heights above ground of the context's points (``arr``: ``x``, ``y``, ``hag``) in the ring
    :data:`CANOPY_RING_M`; ``nan`` where none stands there (nothing to compare with)."""
    x, y = np.asarray(arr["x"], np.float64) - bx, np.asarray(arr["y"], np.float64) - by
    d2 = x * x + y * y
    ring = (d2 >= CANOPY_RING_M[0] ** 2) & (d2 < CANOPY_RING_M[1] ** 2)
    if not ring.any():
        return float("nan")
    return float(height - np.percentile(np.asarray(arr["hag"])[ring], CANOPY_PERCENTILE))


def on_conductor_lines(arr: Mapping[str, Any], x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Which of the points ``(x, y, z)`` (absolute heights) lie on the line of a conductor the wire
    detector found around them (the context's ``arr["conductors"]``, each with its wire's plan
    ``direction``; see :data:`LINE_REACH_M`); all False without conductor points."""
    from scipy.spatial import cKDTree

    c = arr.get("conductors")
    x, y, z = (np.asarray(v, np.float64) for v in (x, y, z))
    out = np.zeros(len(x), bool)
    if c is None or len(c["x"]) == 0 or len(x) == 0:
        return out
    r = LINE_REACH_M
    near = (c["x"] >= x.min() - r) & (c["x"] <= x.max() + r) & (c["y"] >= y.min() - r) & (c["y"] <= y.max() + r)
    if not near.any():
        return out
    cx, cy, cz, u = c["x"][near], c["y"][near], c["z"][near], np.asarray(c["direction"])[near]
    pairs = cKDTree(np.c_[x, y]).query_ball_tree(cKDTree(np.c_[cx, cy]), r)
    counts = np.fromiter(map(len, pairs), np.int64, len(pairs))
    i = np.repeat(np.arange(len(x)), counts)
    j = np.fromiter((k for p in pairs for k in p), np.int64, int(counts.sum()))
    across = np.abs((x[i] - cx[j]) * u[j, 1] - (y[i] - cy[j]) * u[j, 0])
    hit = (across < LINE_ACROSS_M) & (np.abs(z[i] - cz[j]) < LINE_DZ_M)
    out[i[hit]] = True
    return out


def line_share(arr: Mapping[str, Any], x: np.ndarray, y: np.ndarray, z: np.ndarray) -> float:
    """Rule 17: the share of a cluster's points ``(x, y, z)`` that lie on the line of a conductor the
    wire detector found around them (:func:`on_conductor_lines`); 0 without points."""
    return float(on_conductor_lines(arr, x, y, z).mean()) if len(x) else 0.0


def bare_score(verifier: Any, arr: Mapping[str, Any], obj: np.ndarray) -> float:
    """Rule 18: the shape score of a cluster's object (the context's points ``obj``) without its points
    on the conductors' lines (:func:`on_conductor_lines`); ``nan`` when fewer than
    :data:`BARE_MIN_POINTS` are left (the object is its conductors: rule 17's to judge)."""
    obj = np.asarray(obj)
    if len(obj) == 0:
        return float("nan")
    x, y, z, hag = (np.asarray(arr[k])[obj] for k in ("x", "y", "z", "hag"))
    bare = ~on_conductor_lines(arr, x, y, z)
    return float(verifier.score(x[bare], y[bare], hag[bare])) if bare.sum() >= BARE_MIN_POINTS else float("nan")
