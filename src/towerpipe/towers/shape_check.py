"""The shape check of a cluster (rule 9) and the rules that amend it (12, 13 and 18), for
:func:`towerpipe.towers.extract.extract_towers`.

The verifier (:mod:`towerpipe.towers.shape`) scores the object under the cluster's footprint. A
cluster scoring below ``towers.min_shape_score`` (``towers.tall_shape_score`` for one at least
``towers.wire_min_height`` high: rule 13) fails, and its more confident parts are judged instead;
with no part to judge, the core of its object around the cluster's top is (a tower the segmenter
painted with the crowns around it: :func:`towerpipe.towers.shape.core_object`), and then
conductors pointing at it and well below its top keep it (rule 12,
:func:`towerpipe.towers.conductor_rules.vouching_support`). A cluster that passes is scored again
without the points of its object on the detected conductors' lines, and fails below
``towers.min_bare_score`` (rule 18, :func:`towerpipe.towers.conductor_rules.bare_score`).
docs/products.md tells each rule with its measurements.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely

from towerpipe.config import TowersConfig
from towerpipe.towers.conductor_rules import bare_score, vouching_support
from towerpipe.towers.shape import SHAPE_VIEWS, core_object, object_points

__all__ = ["ShapeVerdict", "position_share", "shape_check", "verifier_view"]

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix(h: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser: uint64 to uint64, every bit of the input stirred into every bit."""
    h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return h ^ (h >> np.uint64(31))


def position_share(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """A number in [0, 1) drawn from each point's position (to the millimetre), uniform over
    points: the same point gets the same number whatever the tile, the block or the run."""
    h = np.zeros(len(np.atleast_1d(x)), np.uint64)
    for v in (x, y, z):
        q = np.round(np.asarray(v, np.float64) * 1000.0).astype(np.int64).view(np.uint64)
        h = _mix(h + _GOLDEN + q)
    return (h >> np.uint64(11)).astype(np.float64) * 2.0**-53


def verifier_view(arr: Mapping[str, Any], obj: np.ndarray, max_density: float | None) -> np.ndarray:
    """The points of an object the verifier reads: all of them, or on a tile denser than
    ``max_density`` (``arr["density"]``, :func:`towerpipe.towers.coverage.tile_density`) the share
    ``max_density / density`` of them that :func:`position_share` picks, so that the object is
    seen at a density the verifier learned (it scores a dense lattice lower than the same lattice
    sparser: docs/model.md).
    """
    density = float(arr.get("density", float("nan")))
    if max_density is None or not density > max_density or len(obj) == 0:
        return obj
    x, y, z = (np.asarray(arr[k])[obj] for k in ("x", "y", "z"))
    return obj[position_share(x, y, z) < max_density / density]


@dataclass(frozen=True)
class ShapeVerdict:
    """What :func:`shape_check` made of a cluster."""

    #: The verifier's score of the object under the footprint, or of its core when that passed it (NaN: no object).
    shape: float
    #: Rule 12's conductor support, when the vouch keeps a cluster that fails the score; else ``None``.
    vouch: float | None = None
    #: ``"shape"`` or ``"bare"`` (:data:`towerpipe.towers.extract.TRACE_RULES`) when it fails; ``None``: passes.
    failed: str | None = None
    #: What the failing rule measured.
    value: float = float("nan")
    #: The parts to judge instead of a failed cluster (``split()``'s answer).
    parts: Sequence[Any] = field(default_factory=tuple)
    #: The object judged: indices of the context's points under the footprint (rule 20 reads it too).
    obj: np.ndarray | None = None
    #: Which view the reported ``shape`` scores: ``"object"`` or ``"core"`` (:data:`towerpipe.towers.shape.SHAPE_VIEWS`).
    view: str = SHAPE_VIEWS[0]


def shape_check(
    verifier: Any,
    rules: TowersConfig,
    footprint: shapely.Geometry,
    arr: Mapping[str, Any],
    extent: Any,
    hag: np.ndarray,
    base: tuple[float, float],
    *,
    tall: bool,
    is_rescue: bool,
    split: Callable[[], Sequence[Any]],
    top: tuple[float, float] | None = None,
) -> ShapeVerdict:
    """Judge a cluster by the shape of the object under it (see the module docstring).

    Parameters
    ----------
    verifier
        The shape verifier (:func:`towerpipe.towers.shape.load_verifier`).
    rules
        The tower rules: ``min_shape_score``, ``tall_shape_score``, ``vouch_height``,
        ``vouch_low_height``, ``vouch_low_score``, ``min_wire_support``, ``min_bare_score``,
        ``verifier_density``.
    footprint
        The cluster's xy footprint.
    arr, extent
        The points around the cluster (``x``, ``y``, ``z``, ``hag``, optionally ``conductors`` and
        the tile's ``density``) and
        the extent they cover (:class:`towerpipe.towers.coverage.TileContext`).
    hag
        Heights above ground of the cluster's points.
    base
        The cluster's base (x, y), from which its conductors are measured.
    tall
        The cluster is at least ``wire_min_height`` high (rule 13 applies).
    is_rescue
        The rescue (rule 10) found it: an object with no score fails, and no vouch keeps it.
    split
        Gives the cluster's more confident parts; called only when it fails.
    top
        The cluster's highest point (x, y): a cluster that fails with no part to judge is judged
        again by the core of its object there (:func:`towerpipe.towers.shape.core_object`);
        ``None``: by the whole object only.
    """

    def scored(view: np.ndarray) -> float:  # the verifier's score of the points ``view`` of ``arr``
        return float(verifier.score(arr["x"][view], arr["y"][view], arr["hag"][view])) if len(view) else float("nan")

    obj = object_points(footprint, arr["x"], arr["y"])
    seen = verifier_view(arr, obj, rules.verifier_density)
    shape = scored(seen)
    # rule 13: a cluster as high as the conductor rule judges passes at a lower score, the
    # conductors pointing at it being the second opinion
    needed = rules.tall_shape_score if tall and rules.tall_shape_score is not None else rules.min_shape_score
    vouch, parts, view = None, None, SHAPE_VIEWS[0]  # parts: None until split() is asked
    fails = shape < needed or (is_rescue and np.isnan(shape))
    if fails:
        # the object under it is shaped like a tree, a roof or a crane; or it is a tower standing
        # in crowns the segmenter painted with it: its more confident parts are judged instead
        parts = split()
        if not parts and top is not None:
            # no part to judge: the core of its object around its top, where the crowns do not
            # swamp a lattice (rule 18 then reads that view)
            core = core_object(top, arr["x"], arr["y"], arr["hag"])
            core = np.empty(0, np.int64) if core is None else verifier_view(arr, core, rules.verifier_density)
            score = scored(core)
            if score >= needed:
                shape, seen, fails, view = score, core, False, SHAPE_VIEWS[1]
    if fails:
        if not parts and not is_rescue:
            vouch = vouching_support(rules, arr, extent, hag, *base, shape=shape)
        if vouch is None:
            return ShapeVerdict(shape, failed="shape", value=shape, parts=parts)
    elif rules.min_bare_score > 0 and shape >= needed:
        # rule 18: judged again without the conductors through its object (NaN: too few points left)
        bare = bare_score(verifier, arr, seen)
        if bare < rules.min_bare_score:
            # a cluster its core passed has been split already (into no part)
            return ShapeVerdict(shape, failed="bare", value=bare, parts=split() if parts is None else parts)
    return ShapeVerdict(shape, vouch=vouch, obj=obj, view=view)
