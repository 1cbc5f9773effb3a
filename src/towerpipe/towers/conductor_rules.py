"""What a cluster's conductors say about it: the tower rules of
:func:`towerpipe.towers.extract.extract_towers` that read the wires around a cluster.

- **Support** (rule 7, :func:`support`): the share of the 80-160 m ring reached by a conductor
  pointing at the cluster's base (:func:`towerpipe.towers.wires.wire_support`).
- **Vouch** (rule 12, :func:`vouching_support`): conductors pointing at a cluster the shape check
  drops, its top well above them, keep it.
- **Sides** (rule 14, :func:`conductor_balance`): a tower carries its conductors on both sides of
  its body, or over it; a crane, a mast or a tree *beside* a line has every conductor pointing at
  it on one side. The balance is the share of the conductor points counted by the support that lie
  on the less-held side of the base, or within :data:`OVER_M` of it. A tower's is about 0.5 (0.16
  or more on the twelve calibration zones); a crane's or a tree's beside a line 0-0.15. The rule
  asks it only of a cluster whose shape is in doubt: a tower strung on one side only has its
  conductors on one side too (docs/model.md, "The conductors' sides and a crane's jib"). An
  unknown balance (too few points) drops only a cluster that the vouch keeps.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from towerpipe.config import TowersConfig
from towerpipe.towers.wires import AIM_M, RING_MAX_M, RING_MIN_M, WIRE_MIN_HAG_M, aimed_wire_points, wire_support

__all__ = ["BALANCE_MIN_POINTS", "OVER_M", "conductor_balance", "support", "vouching_support"]

#: A conductor point this close (m, across its wire) to the base is over the body (a shield wire, a
#: conductor of a central crossarm): it counts on both sides.
OVER_M = 1.0
#: The balance is known from this many counted conductor points on (fewer: unknown, ``nan``; a
#: cluster is never dropped for it).
BALANCE_MIN_POINTS = 20


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


def vouching_support(
    rules: TowersConfig, arr: Mapping[str, np.ndarray], extent: Any, hag: np.ndarray, bx: float, by: float
) -> float | None:
    """Rule 12: the conductor support of a cluster the shape check dropped, when its conductors
    vouch for it (a known support of at least ``min_wire_support``, and its top ``hag.max()``
    ``vouch_height`` m or more above their median height in its ring,
    :func:`towerpipe.towers.wires.conductor_heights`, from the support's own search); else ``None``.
    ``(bx, by)``: its base."""
    if rules.vouch_height <= 0:
        return None
    found, heights = support(arr, extent, bx, by, return_heights=True)
    if not found >= rules.min_wire_support:  # NaN (unknown) never vouches
        return None
    if len(heights) == 0 or float(hag.max()) - float(np.median(heights)) < rules.vouch_height:
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
    main = np.linalg.eigh(u.T @ u)[1][:, -1]  # the wires' main direction; a wire's sign is arbitrary
    u = u * np.where(u @ main < 0, -1.0, 1.0)[:, None]
    across = px * u[:, 1] - py * u[:, 0]
    over = np.abs(across) <= OVER_M
    return float(min((across > OVER_M).mean(), (across < -OVER_M).mean()) + over.mean())
