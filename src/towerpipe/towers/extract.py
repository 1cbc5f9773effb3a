"""Towers as objects: the tower rules that turn clusters of predicted tower points into one
record per tower (set by the config's ``towers`` section, :class:`towerpipe.config.TowersConfig`).

The segmenter gives every point a tower probability, from the window as it is
(``prob_single``) and averaged over several views of it (``prob``, see
:func:`towerpipe.inference.views.segment_views`). :func:`extract_towers` turns the points of one
block *and its neighbours* with ``prob_single >= threshold`` into towers (a tower the
segmenter is unsure of in some views is still found), and a tower's points are those of
its cluster with ``prob >= point_threshold`` (a crown painted in one view is left out), of
its foot those that ``rules.foot`` keeps (:mod:`towerpipe.towers.foot`), and the faint points
of its body that ``rules.column`` adds (rule 11, :mod:`towerpipe.towers.column`), less the
crowns beside it that ``rules.crowns`` leaves out (:mod:`towerpipe.towers.crown`):

1. connected components of a 3-D ``cKDTree`` graph (points closer than ``linkage``);
2. a component wider than ``max_extent`` (a chain of falsely predicted wire points
   linking towers) is split into its vertical columns (see :func:`towerpipe.towers.cluster._split_wide`);
3. components whose xy footprints are within ``merge_gap`` of each other are merged (a tower whose
   crossarms were separated from its body), one on two towers' masts split (:mod:`towerpipe.towers.masts`);
4. towers with fewer than ``min_points`` points or lower than ``min_height`` (max HAG)
   are dropped (the paper's towers are >= 10 m high and >= 20 points), and so are
   towers without a confident core: fewer than 10 % of their points at or above
   ``min_core_prob`` (a tower's body comes out of the segmenter near 1; the false
   clusters in trees beside a line hover just above the point threshold);
5. only towers whose footprint centroid lies in the block's half-open bounds
   ``[xmin, xmax) x [ymin, ymax)`` are kept, so a tower across a tile or block edge
   is built from all its points and reported by exactly one block;
6. clusters floating above the ground (lowest point above ``max_base_ratio`` of
   their height) are dropped: pieces of conductor or crossarm;
7. with a ``context`` (the tile points around a tower), each tower gets its
   conductor support (:func:`towerpipe.towers.wires.wire_support`: the share of the 80-160 m
   ring reached by a wire pointing at its base), and towers at least ``wire_min_height``
   high with a support below ``min_wire_support`` are dropped: a transmission tower
   carries conductors to the next tower, a crane or a mast does not;
8. with a ``context``, each tower gets its shape score (:mod:`towerpipe.towers.shape`: the
   verifier's judgement of the object under its footprint, from positions only), and towers
   scoring below ``min_shape_score`` are dropped: the crowns of trees that the segmenter
   paints, roofs, cranes.
   This check runs before rule 7 (it is cheap and drops most clusters). A cluster it drops
   is clustered again from its points at or above each of ``split_thresholds`` in turn
   (until one gives clusters of at least ``min_split_points``), and then, once none does, its own
   points are linked again at ``split_linkage`` (tighter than ``linkage``); each part is judged by
   rules 4-8: a tower standing among the crowns that the segmenter paints with it.

The split is rule 9. Rule 10, the rescue (``rescue_threshold``, with the shape check only):
after the other rules, the points at or above ``rescue_threshold`` that no accepted tower
holds are clustered and each cluster is judged by rules 4-8 (of rule 9 only the tighter linkage;
its highest probability, not its 90th percentile, must reach ``min_core_prob``), its points those at or above
``rescue_threshold``: a thin pole or a sparse real lattice that the segmenter paints mostly
at 0.1-0.3 is found and outlined when its object is shaped like a tower.

Rules 12-23 (docs/products.md tells each with its measurements; 0 turns each off):

12. the conductors' vouch (``vouch_height``): a cluster the shape check drops, with no split part to
    judge instead, is kept when conductors point at it and its top stands ``vouch_height`` m above them
    (``vouch_low_height`` m from a score of ``vouch_low_score``; :mod:`towerpipe.towers.conductor_rules`);
13. tall clusters (``tall_shape_score``, ``None``: off): a cluster at least ``wire_min_height`` high
    passes the shape check at this lower score, rule 7 judging it next;
14. the conductors' sides (``min_conductor_balance``): a cluster whose shape is in doubt is dropped
    when the conductors pointing at it lie on one side of its base
    (:func:`towerpipe.towers.conductor_rules.conductor_balance`);
15. a crane's jib (``max_arm_reach``): a tall cluster whose narrow plan reaches this far on one side is
    dropped, and the rescue leaves its points alone (:mod:`towerpipe.towers.plan`);
16. nothing standing (``min_stand``): a cluster whose points over every 1 m plan cell lie within this
    height range is dropped (:func:`towerpipe.towers.plan.tallest_stand`);
17. on a conductor's line (``max_line_share``, 1: off): a cluster more than this share of whose points
    lie on the lines of the conductors the wire detector finds around it is dropped
    (:func:`towerpipe.towers.conductor_rules.line_share`);
18. a crown under conductors (``min_bare_score``): a cluster that passes the shape check is judged
    again without the points of its object on those lines, and dropped below this score;
19. the conductors near it (``min_near_balance``): where the support is unknown, a cluster is dropped
    when the conductors within 80 m lie on one side of it or none points at it; a tall one under
    ``min_wire_support`` is kept when they hang on both sides of it or over it
    (:func:`towerpipe.towers.conductor_rules.near_balance`);
20. a line over it (``under_line``): a cluster with at least this many conductor points within 25 m
    pointing at it more than 2 m over its top, and fewer at or below, is dropped: a crown under a line
    (:func:`towerpipe.towers.conductor_rules.under_line`);
21. a tall cluster's core (``tall_core_prob``, ``None``: off): one at least ``wire_min_height`` high needs
    this core probability (rule 4, the rescue's too) instead of ``min_core_prob``;
22. a crown in the canopy (``canopy``): a low cluster with few conductors near it that hardly rises over
    what stands 20-40 m around it is dropped (:func:`towerpipe.towers.conductor_rules.canopy_clearance`);
23. two towers under one cluster's tops (``peak_share``): an accepted cluster with two prominent peaks,
    each over a body and a base of its own, is parted and each part judged again (:mod:`towerpipe.towers.peaks`).

A tower's id is the zone registry's when it matches a registered tower, else made from
the centroid where it is first seen (:mod:`towerpipe.towers.registry`): it depends on the tower's
points and the registry, never on file or processing order nor on the zone's name. The clustering is
:mod:`towerpipe.towers.cluster`'s.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from towerpipe.config import TowersConfig
from towerpipe.io.fields import GEOMETRY_GRID, join_values
from towerpipe.towers.cluster import _as_pred, _footprint, cluster_towers, gather_points
from towerpipe.towers.column import column_mask
from towerpipe.towers.conductor_rules import canopy_clearance, conductor_balance, line_share, near_balance, under_line
from towerpipe.towers.conductor_rules import support as conductor_support
from towerpipe.towers.crown import crown_mask
from towerpipe.towers.foot import foot_mask
from towerpipe.towers.peaks import peak_parts
from towerpipe.towers.plan import JIB_MAX_WIDTH_M, arm_reach, base, tallest_stand
from towerpipe.towers.records import empty_towers, tower_record, towers_frame
from towerpipe.towers.registry import assign_ids
from towerpipe.towers.shape import load_verifier, object_points
from towerpipe.towers.shape_check import shape_check
from towerpipe.towers.split import RELINK, split_parts

#: What decided a cluster in a ``trace`` of :func:`extract_towers`: its core probability (rule 6), floating
#: (7), nothing standing (16), too few points to report, a crane's jib (15), no context for a rescue, on a
#: conductor's line (17), the shape check (9), a crown under conductors (18), a line over it (20), a crown in
#: the canopy (22), the conductor support (8), the conductors on one side (14) or near it (19), or accepted.
TRACE_RULES = tuple(
    "core floating stands points jib context line shape bare under canopy wires sides near accepted".split()
)


@dataclass
class ExtractedTowers:
    """What :func:`extract_towers` finds for one block."""

    #: One row per tower the block owns, columns :data:`~towerpipe.towers.records.TOWER_COLUMNS` and the footprint
    #: Polygon, sorted by ``tower_id``; empty (full schema) when there is none.
    towers: gpd.GeoDataFrame
    #: ``tower_id`` → (block names, point indices) of the points of every accepted tower with
    #: points in this block, owned or not (a neighbour's tower across the edge passes the same
    #: rules on the same points and tiles there), for the classified block: its class-15
    #: points and their tower id (:func:`towerpipe.io.members.save_members`).
    members: dict[int, tuple[np.ndarray, np.ndarray]]
    #: ``{"tower_id", "footprint_wkt", "blocks"}`` of each tower that has points in this block
    #: but is owned by a neighbour (its centroid lies there); the block's QA uses them so that
    #: a labelled edge tower reported by the neighbour is not counted as missed.
    neighbours: list[dict[str, Any]]


def _decided(trace: list[dict[str, Any]], xyz: np.ndarray, rescue: bool, rule: str, value: float) -> None:
    """Record in ``trace`` what decided the cluster of points ``xyz`` (:data:`TRACE_RULES`)."""
    trace.append({"x": xyz[:, 0], "y": xyz[:, 1], "rescue": bool(rescue), "rule": rule, "value": float(value)})


def _not_traced(rule: str, value: float) -> None:
    """No trace asked for."""


def extract_towers(
    preds: Sequence[Any],
    block_name: str,
    block_bounds: Sequence[float],
    rules: TowersConfig,
    *,
    zone: str,
    point_threshold: float | None,
    merge_gap: float = 1.0,
    max_extent: float = 25.0,
    min_width: float = 1.0,
    model_meta: Mapping[str, Any] | None = None,
    source_files: Mapping[str, str] | None = None,
    crs: Any = None,
    processed_at: str | None = None,
    context: Callable[[float, float], tuple[Mapping[str, np.ndarray], Sequence[float]] | None] | None = None,
    registry: gpd.GeoDataFrame | None = None,
    trace: list[dict[str, Any]] | None = None,
) -> ExtractedTowers:
    """Towers owned by one block, built from the predictions of the block and its neighbours.

    Parameters
    ----------
    preds
        Prediction files (paths, ``PredFile`` objects or ``(arrays, meta)`` pairs)
        of the block **and its neighbours**, so that a tower across a block edge
        is complete.
    block_name
        The block whose towers are returned (recorded in ``block``).
    block_bounds
        ``(xmin, ymin, xmax, ymax)`` of the block; a tower belongs to the block
        when its footprint centroid is in ``[xmin, xmax) x [ymin, ymax)``.
    rules
        The tower rules (the config's ``towers`` section):

        - ``threshold``: minimum single-view tower probability (``prob_single``) of a point;
        - ``linkage``, ``min_points``, ``min_height``: clustering parameters, see
          :func:`towerpipe.towers.cluster.cluster_towers`;
        - ``min_core_prob``: a tower whose 90th percentile of single-view point probabilities
          is below this is dropped (0 keeps every cluster); the LAS keeps its points'
          probabilities. ``prob_mean`` and ``prob_max`` of a tower are of the same probabilities;
        - ``min_wire_support``, ``wire_min_height``: towers with a max HAG of at least
          ``wire_min_height`` (m) and a wire support below ``min_wire_support`` are dropped unless
          rule 19 keeps them (0 keeps every tower; an unknown, NaN, support drops one only by rule 19);
        - ``max_base_ratio``: towers whose lowest point is higher than this share of their
          height above ground are dropped (1 keeps all): a tower stands on the ground, a
          floating cluster is a piece of conductor or crossarm;
        - ``verifier``, ``min_shape_score``: with a ``context``, towers whose shape score
          (:class:`towerpipe.towers.shape.ShapeVerifier`) is below ``min_shape_score`` are
          dropped (``verifier: none`` or 0 keeps all; without a context the score is NaN).
        - ``tall_shape_score``: rule 13, the shape score a cluster at least ``wire_min_height`` high
          needs instead of ``min_shape_score`` (``None``: ``min_shape_score``); the conductor rule
          judges it next;
        - ``split_thresholds``, ``min_split_points``, ``split_linkage``: a cluster the shape check
          drops is clustered again from its points at or above each of these in turn, then (once
          none parts it) from all its points at ``split_linkage`` (0: not), and each part of at
          least ``min_split_points`` points (and ``min_points``) is judged (``()`` and 0: never);
        - ``rescue_threshold``; ``vouch_height``, ``vouch_low_height``, ``vouch_low_score``;
          ``peak_share``: rules 10, 12 and 23 (module docstring; 0: off);
        - ``min_conductor_balance``, ``max_arm_reach``, ``min_stand``, ``max_line_share``, ``min_bare_score``,
          ``min_near_balance``: rules 14-19 (module docstring; 0, or 1 for ``max_line_share``: off);
        - ``foot``, ``column``, ``crowns``: which of a tower's points are reported
          (:mod:`towerpipe.towers.foot`, :mod:`towerpipe.towers.column`: rule 11,
          :mod:`towerpipe.towers.crown`); never whether the tower is.
    zone
        Zone name (recorded in ``zone``; not part of the id).
    point_threshold
        The points of a tower are its cluster's points whose view-averaged probability
        (``prob``) is at or above this (``n_points`` and ``members``); ``None``: all of
        them. A tower with fewer than ``rules.min_points`` such points is dropped; the others'
        are trimmed at the foot and at the crowns beside them and given the faint points of their
        body (``rules.foot``, ``rules.crowns``, ``rules.column``: the module docstring), never
        under ``rules.min_points``.
    merge_gap, max_extent
        Clustering parameters, see :func:`towerpipe.towers.cluster.cluster_towers`.
    min_width
        Footprints thinner than this (m) are buffered to this width.
    model_meta
        ``{"name": ..., "version": ...}``; default: ``meta["model"]`` of the first
        prediction file.
    source_files
        Block name → input point-cloud path; a tower lists the files of the blocks
        its points come from (made absolute).
    crs
        CRS of the result (WKT, EPSG string, ``pyproj.CRS``); default:
        ``meta["crs_wkt"]`` of the first prediction file.
    processed_at
        ISO timestamp recorded in every record (default: now, UTC).
    context
        ``context(cx, cy)`` gives the points around a tower centre, ``({"x", "y", "z",
        "hag"} arrays, covered extent)``, or ``None``; then ``wire_support`` is
        computed (:func:`towerpipe.towers.wires.wire_support`) and the shape score. Without it
        both columns are NaN. The arrays may hold ``"conductors"`` (the wire points around, each
        judged in its own tile: :class:`towerpipe.towers.coverage.TileContext`), from which the
        support is then measured.
    registry
        The zone's tower registry (:func:`towerpipe.products.registry_file.read_registry`): a tower
        matching a registered one keeps its id, review status and ``first_seen``; others
        get a new id from their location (:func:`towerpipe.towers.registry.assign_ids`). Ids are
        assigned over every accepted tower the job sees (its own and those of its
        neighbours it reaches into), so both jobs give a tower across an edge one id.
    trace
        A list that receives, for every cluster judged (the splits' and the rescue's parts
        included), ``{"x", "y"}`` (its points), ``"rescue"`` and the rule that decided it:
        ``"rule"`` one of :data:`TRACE_RULES` and ``"value"`` what the rule measured
        (:mod:`towerpipe.evaluation.trace` tells from it why a true tower was missed).

    Returns
    -------
    ExtractedTowers
        The block's towers, the points of the accepted towers with points in the block
        (``members``) and the towers with points in the block that a neighbour owns
        (``neighbours``).
    """
    preds = [_as_pred(p) for p in preds]
    metas = [m for _, m in preds]
    if crs is None:
        crs = next((m["crs_wkt"] for m in metas if m.get("crs_wkt")), None)
    if model_meta is None:
        model_meta = next((m["model"] for m in metas if m.get("model")), {})
    if processed_at is None:
        processed_at = datetime.now(UTC).replace(microsecond=0).isoformat()
    members: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    neighbours: list[dict[str, Any]] = []
    verifier = load_verifier(rules.verifier) if context is not None else None
    # rule 10 needs the shape check: without it a rescue would only be a lower threshold
    checked = verifier is not None and rules.min_shape_score > 0
    rescue = float(rules.rescue_threshold) if checked and 0 < rules.rescue_threshold < rules.threshold else 0.0
    # the column (rule 11) may take points fainter than the clusters' and the rescue's
    floor, column_t = rescue or rules.threshold, float(rules.column["threshold"])
    pts = gather_points(preds, column_t if 0 < column_t < floor else floor)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)

    def cluster(idx: np.ndarray, min_points: int = rules.min_points, linkage: float = rules.linkage) -> np.ndarray:
        """Tower labels of the points ``idx`` (the clustering of rules 1-4)."""
        return cluster_towers(
            xyz[idx],
            pts["hag"][idx],
            linkage=linkage,
            merge_gap=merge_gap,
            mast_prominence=rules.mast_prominence,
            max_extent=max_extent,
            min_points=min_points,
            min_height=rules.min_height,
        )

    # a split's parts (rule 9) need min_split_points too, more than a cluster of the main pass when
    # min_points is lowered: cut from a crown at a higher probability, a small part is mostly its top
    part_points = max(rules.min_points, rules.min_split_points)
    cluster_part = partial(cluster, min_points=part_points)
    peaks = {"linkage": rules.linkage, "prominence": rules.mast_prominence, "share": rules.peak_share}
    peaks["min_points"] = part_points
    relink_part = partial(cluster_part, linkage=rules.split_linkage) if rules.split_linkage > 0 else None
    # a rescue's cluster (rule 10) is parted by the tighter linkage only: its points are the faint ones
    relink_steps = (RELINK,) if relink_part else ()
    split_steps = (*(float(t) for t in rules.split_thresholds), *relink_steps)

    def groups(idx: np.ndarray) -> list[np.ndarray]:
        """The clusters of the points ``idx``, each as indices into ``pts``."""
        labels = cluster(idx)
        order = np.argsort(labels, kind="stable")
        order = order[labels[order] >= 0]
        return [idx[g] for g in np.split(order, np.flatnonzero(np.diff(labels[order])) + 1) if g.size]

    def held_by_clusters() -> np.ndarray:
        """Which points of ``pts`` the clusters of the accepted towers hold."""
        held = np.zeros(len(pts["x"]), bool)
        for a in accepted:
            held[a[0]] = True
        return held

    sources = dict(source_files or {})
    accepted: list[tuple[Any, ...]] = []
    main = np.flatnonzero(pts["prob_single"] >= rules.threshold)
    # each cluster with the split thresholds still to try on it (rule 9), whether the rescue found
    # it (rule 10) and whether it is a part of rule 23's
    rows, geoms, rescued = [], [], False
    cranes = np.zeros(len(pts["x"]), bool)  # the points of the clusters rule 15 dropped
    queue = deque((g, split_steps, False, False) for g in groups(main))
    while queue or (rescue and not rescued):
        if not queue:
            # rule 10, the rescue: what the segmenter painted faintly (a thin pole, a sparse
            # lattice) and no accepted tower holds, clustered from the points at or above
            # towers.rescue_threshold and judged by the same rules (of the split only the tighter
            # linkage; its highest probability, not its 90th percentile, must reach min_core_prob,
            # and the shape check must have judged it), its points those at or above that threshold
            rescued = True
            held = held_by_clusters() | cranes  # a crane rule 15 dropped is not found again, wider
            queue.extend(
                (g, relink_steps, True, False)
                for g in groups(np.flatnonzero(pts["prob_single"] >= rescue))
                if not held[g].any()
            )
            continue
        g, splits, is_rescue, parted = queue.popleft()
        decided = partial(_decided, trace, xyz[g], is_rescue) if trace is not None else _not_traced
        core_q, g_threshold = (1.0, rescue) if is_rescue else (0.9, point_threshold)
        core, hag = float(np.quantile(pts["prob_single"][g], core_q)), pts["hag"][g].astype(np.float64)
        if rules.min_core_prob > 0 and core < rules.core_needed(hag.max()):
            decided("core", core)
            continue
        if hag.min() > rules.max_base_ratio * hag.max():
            decided("floating", hag.min() / max(hag.max(), 1e-9))
            continue  # floating: a piece of conductor or crossarm, not a tower standing on the ground
        stand = tallest_stand(xyz[g]) if rules.min_stand > 0 else float("inf")
        if stand < rules.min_stand:
            decided("stands", stand)
            continue  # rule 16: nothing in it stands over any spot of its plan, a piece of conductor
        xy = xyz[g, :2]
        footprint = shapely.set_precision(_footprint(xy, min_width), GEOMETRY_GRID)  # as written: 1 cm
        c = footprint.centroid
        touched = sorted(set(pts["block"][g].tolist()))
        owned = bool(block_bounds[0] <= c.x < block_bounds[2] and block_bounds[1] <= c.y < block_bounds[3])
        if not owned and str(block_name) not in touched:
            continue  # a neighbour's tower that does not reach this block
        g_pts = g if g_threshold is None else g[pts["prob"][g] >= g_threshold]
        if len(g_pts) < rules.min_points:
            decided("points", len(g_pts))
            continue  # what would be reported is too few points for a tower (the paper's 20)
        # the tower's base (median xy of its lowest third): a crane's footprint centroid lies out
        # along its jib, its base is the mast; the conductors are measured from it
        bx, by = (float(v) for v in base(xy, hag))
        tall = hag.max() >= rules.wire_min_height
        if tall and rules.max_arm_reach > 0:
            reach, width = arm_reach(xy, hag, (bx, by))
            if width <= JIB_MAX_WIDTH_M and reach >= rules.max_arm_reach:
                decided("jib", reach)
                cranes[g] = True
                continue  # rule 15: a narrow arm reaching far out on one side, a crane's jib
        prob = pts["prob_single"][g].astype(np.float64)
        support, shape, view = float("nan"), float("nan"), None  # view: what the shape score judged
        ctx = context(float(c.x), float(c.y)) if context is not None else None
        if is_rescue and ctx is None:
            decided("context", float("nan"))
            continue  # a rescue stands on the shape check, which needs the points around it
        if ctx is not None:
            arr, extent = ctx
            if rules.max_line_share < 1:
                on_line = line_share(arr, *xyz[g].T)
                if on_line > rules.max_line_share:
                    decided("line", on_line)
                    continue  # rule 17: it lies along the conductors found around it, a piece of one
            vouch = obj = None  # rule 12's conductor support when it keeps a cluster; the object judged
            # the shape check first (rules 9, 12, 13 and 18): it is cheap, and it drops most clusters (crowns)
            if verifier is not None:
                split = partial(split_parts, g, pts["prob_single"], cluster_part, splits, relink_part)
                top, kw = xy[int(np.argmax(hag))], {"tall": tall, "is_rescue": is_rescue, "split": split}
                verdict = shape_check(verifier, rules, footprint, arr, extent, hag, (bx, by), top=tuple(top), **kw)
                shape, vouch, obj, view = verdict.shape, verdict.vouch, verdict.obj, verdict.view
                if verdict.failed:
                    decided(verdict.failed, verdict.value)
                    queue.extend((part, rest, is_rescue, parted) for part, rest in verdict.parts)
                    continue
            canopy = rules.canopy["conductors"] > 0 and hag.max() < rules.canopy["max_height"]
            if rules.under_line > 0 or canopy:
                obj = object_points(footprint, arr["x"], arr["y"]) if obj is None else obj
                over, under = under_line(arr, bx, by, float(xyz[g, 2].max()), obj)
                if over >= rules.under_line and under < rules.under_line:  # never with under_line 0
                    decided("under", under)
                    continue  # rule 20: a line's conductors pass over it and none hangs from it, a crown
                few = canopy and over + under < rules.canopy["conductors"]  # only then is the wood measured
                if few and (rise := canopy_clearance(arr, bx, by, float(hag.max()))) < rules.canopy["clearance"]:
                    decided("canopy", rise)
                    continue  # rule 22: no conductor hangs near it and it hardly rises over the wood
            support = conductor_support(arr, extent, bx, by) if vouch is None else vouch
            # rule 19: where the ring says nothing (unknown) or too little (a tall cluster under
            # min_wire_support), the conductors nearer than the ring decide
            weak = tall and support < rules.min_wire_support
            near = near_balance(arr, bx, by) if rules.min_near_balance > 0 and (weak or np.isnan(support)) else np.nan
            if weak and not near >= rules.min_near_balance:
                decided("wires", support)
                continue  # rule 8, unless the conductors near it hang on both sides of it or over it
            if np.isnan(support) and near < rules.min_near_balance:
                decided("near", near)
                continue  # its ring out of the data, a line passing beside it
            # rule 14 asks where the conductors lie only of a cluster whose shape is in doubt (kept by
            # rule 12 or 13, no shape score, or a rescue's): a one-sided line can hang from a tower
            doubted = vouch is not None or is_rescue or not shape >= rules.min_shape_score
            if (tall or vouch is not None) and doubted and rules.min_conductor_balance > 0:
                balance = conductor_balance(arr, bx, by)
                # unknown (NaN) drops only what rule 12 keeps against the shape check: its vouch then
                # rests on conductors too few to say where they lie
                if balance < rules.min_conductor_balance or (vouch is not None and np.isnan(balance)):
                    decided("sides", balance)
                    continue  # rule 14: every conductor on one side, a crane or a tree beside a line
        if rules.peak_share > 0 and not parted and (sub := peak_parts(xyz[g], hag, **peaks)).max() > 0:
            queue.extend((g[sub == k], splits, is_rescue, True) for k in range(int(sub.max()) + 1))
            continue  # rule 23: two towers linked under their tops, each part judged on its own
        decided("accepted", shape)
        accepted.append((g, g_pts, footprint, touched, owned, support, shape, view, hag, prob))
    # the points each accepted tower reports (never whether it is one): its foot trimmed, then its column
    # (rule 11) from the blocks its cluster touches, whose jobs judge it and whose merges classify them,
    # then the crowns beside it left out
    held = held_by_clusters()

    def trim(idx: np.ndarray, mask: Callable[..., np.ndarray], rule: Mapping[str, Any]) -> np.ndarray:
        kept = idx[mask(xyz[idx, 0], xyz[idx, 1], pts["hag"][idx], rule)]
        return kept if len(kept) >= rules.min_points else idx  # too few left: the tower keeps them all

    for i, (g, g_pts, footprint, touched, *rest) in enumerate(accepted):
        g_pts = trim(g_pts, foot_mask, rules.foot)
        f = np.flatnonzero(~held & np.isin(pts["block"], touched))
        take = f[column_mask(*xyz[g_pts, :2].T, *xyz[f, :2].T, pts["hag"][f], pts["prob"][f], rules.column)]
        held[take] = True
        accepted[i] = (g, trim(np.concatenate([g_pts, take]), crown_mask, rules.crowns), footprint, touched, *rest)
    if not accepted:
        return ExtractedTowers(empty_towers(crs), members, neighbours)
    ids, first_seen, review = assign_ids([a[2] for a in accepted], registry)
    stamp = pd.Timestamp(processed_at)
    stamp = stamp.tz_localize("UTC") if stamp.tzinfo is None else stamp.tz_convert("UTC")
    for (g, g_pts, footprint, touched, owned, support, shape, view, hag, prob), tid, first, rev in zip(
        accepted, ids.tolist(), first_seen, review
    ):
        members[tid] = (pts["block"][g_pts], pts["point_index"][g_pts])
        if not owned:
            # reported by the neighbour that holds its centroid (the same rules on the same
            # points and tiles decide there); listed for this block's QA
            neighbours.append({"tower_id": tid, "footprint_wkt": footprint.wkt, "blocks": join_values(touched)})
            continue
        rows.append(
            tower_record(
                footprint,
                xyz[g, 2],
                hag,
                prob,
                tower_id=tid,
                zone=zone,
                block=block_name,
                block_bounds=block_bounds,
                touched=touched,
                n_points=len(g_pts),
                shape_score=shape,
                shape_view=view,
                wire_support=support,
                review_status=rev,
                first_seen=first,
                processed_at=stamp,
                source_files=sources,
                model_meta=model_meta,
            )
        )
        geoms.append(footprint)
    towers = towers_frame(rows, geoms, crs)
    return ExtractedTowers(towers, members, neighbours)
