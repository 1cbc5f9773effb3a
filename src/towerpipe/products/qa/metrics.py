"""The numbers of the QA pages: inputs read, limits (and the flags they raise on a tower), density, accuracy, the data edge.

Everything here is plain data (numbers, dicts, arrays); :mod:`towerpipe.products.qa.plots` draws
and :mod:`towerpipe.products.qa.pages` renders.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from towerpipe import classes


@dataclass(frozen=True)
class Limits:
    """Limits that flag a block or a tower for a human look.

    No defaults here: the schema holds them (the config's ``qa`` section, and the tower
    rules of its ``towers`` section, :attr:`FROM_TOWERS`); :meth:`from_config` reads a
    validated config.
    """

    #: Median points / m² over non-empty cells below this: the block is flagged.
    min_density: float
    #: Share of points classified ground below this: the block is flagged.
    min_ground_ratio: float
    #: A tower footprint closer than this (m) to the edge of the data may be cut: flagged.
    edge_margin_m: float
    #: Mean probability of a tower's points below this: the tower is flagged.
    min_tower_prob: float
    #: Conductor support of a tower below this: flagged (``towers.min_wire_support``).
    min_wire_support: float
    #: The conductor rule applies from this height (m) (``towers.wire_min_height``).
    wire_min_height: float
    #: Share of windows that passed the classifier gate above this: the block is flagged.
    max_gate_ratio: float
    #: Tower recall against input labels (when present) below this: the block is flagged.
    min_recall: float
    #: Tower precision against input labels (when present) below this: the block is flagged.
    min_precision: float
    #: Share of the block's labelled tower points in a reported tower below this: flagged.
    min_point_recall: float
    #: Labelled clusters with fewer points are not towers (``towers.min_points``).
    min_truth_points: int
    #: Labelled clusters standing on two towers' masts are two towers (``towers.mast_prominence``).
    mast_prominence: float
    #: Shape score of a tower below this: flagged (``towers.min_shape_score``); only rule 12 (the
    #: conductors' vouch, ``towers.vouch_height``, ``vouch_low_height``) or rule 13 (tall clusters,
    #: ``towers.tall_shape_score``) report a tower with such a score.
    min_shape_score: float

    #: The limits that are tower rules: field → key of the config's ``towers`` section.
    FROM_TOWERS: ClassVar[Mapping[str, str]] = {
        "min_wire_support": "min_wire_support",
        "wire_min_height": "wire_min_height",
        "min_truth_points": "min_points",
        "mast_prominence": "mast_prominence",
        "min_shape_score": "min_shape_score",
    }

    def tower_flags(self, tower: Any, to_edge: float, *, support_measured: bool = True) -> list[str]:
        """Why a tower needs a look (none: it does not).

        Parameters
        ----------
        tower
            A row of the tower table (:data:`towerpipe.towers.records.TOWER_FIELDS`).
        to_edge
            Distance (m) from its footprint to the edge of the data (NaN: unknown).
        support_measured
            The table has ``wire_support`` (its NaN then means the ring lay outside the data).
        """
        from towerpipe.towers.shape import PEAK_CORE_RADIUS, SHAPE_VIEWS

        out = []
        if math.isfinite(to_edge) and to_edge < self.edge_margin_m:
            out.append(
                f"footprint {to_edge:.1f} m from the edge of the data (zone edge, or a neighbour "
                f"without points): the tower may be cut"
            )
        if tower.prob_mean < self.min_tower_prob:
            out.append(f"low mean probability {tower.prob_mean:.2f}")
        support = float(getattr(tower, "wire_support", float("nan")))
        tall, near = tower.height_m >= self.wire_min_height, "kept by rule 19: conductors within 80 m hang from it"
        if math.isfinite(support) and support < self.min_wire_support:
            out.append(
                f"few conductors found (support {support:.2f}){', ' + near if tall else ': a pole, or not a tower?'}"
            )
        elif not math.isfinite(support) and support_measured and tall:
            out.append(f"conductor support not measured (80-160 m ring outside the data); {near}, or too few")
        shape = float(getattr(tower, "shape_score", float("nan")))
        if math.isfinite(shape) and shape < self.min_shape_score:
            # only rule 12 (the conductors' vouch) or rule 13 (tall clusters) keep such a tower,
            # and rule 13 keeps one whose support could not be measured; the score is shown
            # rounded down, so it never reads as the threshold
            why = f"conductor support {support:.2f}" if math.isfinite(support) else "its conductor support unknown"
            out.append(
                f"shaped like a tree (shape score {math.floor(shape * 1000) / 1000:.3f}, under "
                f"{self.min_shape_score:g}), kept by rule 12 or 13 with {why}: a tower among crowns, or a "
                "tall tree beside a line?"
            )
        elif getattr(tower, "shape_view", None) == SHAPE_VIEWS[1]:  # rule 9 passed it by its object's core
            out.append(
                f"shaped like a tower only near its top (shape score {shape:.3f} within {PEAK_CORE_RADIUS:g} m "
                "of it; the whole object looks like crowns): a tower among trees, or a crown?"
            )
        return out

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> Limits:
        """The limits of a validated config: its ``qa`` section and :attr:`FROM_TOWERS` of ``towers``."""
        qa, towers = config["qa"], config["towers"]
        return cls(
            **{
                f.name: towers[cls.FROM_TOWERS[f.name]] if f.name in cls.FROM_TOWERS else qa[f.name]
                for f in fields(cls)
            }
        )


#: Points handled at a time by the per-point figures of a block (:func:`point_chunks`): a
#: million, so a 20 M point block needs no temporary array of its size.
CHUNK_POINTS = 1 << 20


def point_chunks(n: int, size: int = CHUNK_POINTS) -> Iterable[slice]:
    """Slices of ``size`` points covering ``range(n)`` (the QA's per-point work, a chunk at a time)."""
    return (slice(i, min(i + size, n)) for i in range(0, n, size))


#: Header bounds of adjoining blocks meet up to rounding (a block's max is its last point,
#: not the next block's min): boxes are grown by this much (m) before they are joined.
SEAM_TOLERANCE_M = 1.0


def tower_flag_reason(n: int, tower_id: Any, reason: str) -> str:
    """The text of a tower's flag on a block's QA page (``tower`` code): its number on the page, its
    id and why it needs a look; the QA index reads the reviewed ones back by it."""
    return f"tower {n} ({tower_id}): {reason}"


def jsonable(obj: Any) -> Any:
    """``obj`` with numpy scalars/arrays, paths and non-finite floats made JSON-ready."""
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(float(obj)) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def sum_dicts(dicts: Iterable[Mapping[str, Any] | None]) -> dict[str, float]:
    """Key-wise sum of the numeric values of several dicts."""
    out: dict[str, float] = {}
    for d in dicts:
        for k, v in (d or {}).items():
            if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
                out[k] = out.get(k, 0) + v
    return out


# --------------------------------------------------------------------------- inputs
def load_classified(src: str | os.PathLike[str] | Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Points of a classified block: ``x, y, z, classification`` and, when present, ``prob``, ``hag``.

    Parameters
    ----------
    src
        A mapping of arrays (or of :class:`~towerpipe.io.blockcache.ColumnReader`, kept as they
        are), or the path of the classified LAS/LAZ written by the merge step (``prob`` from
        its ``TowerProbability`` extra dimension).
    """
    if isinstance(src, Mapping):
        from towerpipe.io.blockcache import ColumnReader

        # a column read a chunk at a time stays so (the figures take it a chunk at a time)
        out = {k: v if isinstance(v, ColumnReader) else np.asarray(v) for k, v in src.items()}
    else:
        import laspy

        from towerpipe.io.lasformat import PROB_DIMENSION

        las = laspy.read(src)
        out = {
            "x": np.asarray(las.x),
            "y": np.asarray(las.y),
            "z": np.asarray(las.z),
            "classification": np.asarray(las.classification, dtype=np.uint8),
        }
        names = {n.lower(): n for n in las.point_format.extra_dimension_names}
        if PROB_DIMENSION.lower() in names:
            out["prob"] = np.asarray(las[names[PROB_DIMENSION.lower()]], dtype=np.float32)
    missing = [k for k in ("x", "y", "z", "classification") if k not in out]
    if missing:
        raise ValueError(f"classified points lack {missing}")
    return out


def read_benchmark(path: str | os.PathLike[str]) -> dict[str, float]:
    """Wall time ``s`` and peak memory ``max_rss`` (MB) of a Snakemake benchmark TSV.

    With several repetitions (rows) the mean time and the largest peak are used;
    columns that are missing or ``NA``/``-`` are left out. Snakemake samples a job's memory
    while it runs: a row whose ``cpu_time`` is 0 was not sampled while the job worked (a job
    of a second or less), and its ``max_rss`` (the wrapper's few MB) is left out too.
    """
    lines = [ln.rstrip("\n").split("\t") for ln in Path(path).read_text().splitlines() if ln.strip()]
    if len(lines) < 2:
        return {}
    head, rows = lines[0], lines[1:]

    def value(row: list[str], col: str) -> float | None:
        try:
            return float(row[head.index(col)])
        except (ValueError, IndexError):
            return None

    out: dict[str, float] = {}
    for col, key, agg in (
        ("s", "seconds", np.mean),
        ("max_rss", "max_rss_mb", np.max),
        ("cpu_time", "cpu_seconds", np.mean),
    ):
        if col in head:
            vals = [
                v
                for r in rows
                if (v := value(r, col)) is not None and not (col == "max_rss" and value(r, "cpu_time") == 0.0)
            ]
            if vals:
                out[key] = float(agg(vals))
    return out


def read_towers(towers: Any) -> Any:
    """A GeoDataFrame of towers from ``None``, a GeoPackage path or a frame."""
    import geopandas as gpd

    if towers is None:
        from towerpipe.towers.records import empty_towers

        return empty_towers()
    if isinstance(towers, (str, os.PathLike)):
        from towerpipe.products.gpkg_read import read_towers as read_gpkg

        return read_gpkg(towers)
    return gpd.GeoDataFrame(towers)


# --------------------------------------------------------------------------- density
def density_grid(x: np.ndarray, y: np.ndarray, bounds: Sequence[float]) -> tuple[np.ndarray, dict[str, float]]:
    """Points per m² on a grid of about 120 cells a side (north up) and its statistics.

    Returns
    -------
    grid, stats
        ``grid`` (rows north to south); ``stats``: ``density_cell_m``, ``density_median``
        and ``density_p05`` over non-empty cells, ``empty_cells_pct``.
    """
    xmin, ymin, xmax, ymax = bounds
    cell = max(2.0, max(xmax - xmin, ymax - ymin) / 120)
    nx = max(1, int(math.ceil((xmax - xmin) / cell)))
    ny = max(1, int(math.ceil((ymax - ymin) / cell)))
    # points per cell by integer binning (np.histogram2d is ~10x slower on millions of points),
    # a chunk at a time (no temporary of the block's size)
    h = np.zeros(nx * ny, np.int64)
    for s in point_chunks(len(x)):
        ix = np.clip(((np.asarray(x[s]) - xmin) * (1.0 / cell)).astype(np.int32), 0, nx - 1)
        iy = np.clip(((np.asarray(y[s]) - ymin) * (1.0 / cell)).astype(np.int32), 0, ny - 1)
        ix *= ny
        ix += iy
        h += np.bincount(ix, minlength=nx * ny)
    h = h.reshape(nx, ny).astype(np.float64)
    dens = h.T[::-1] / (cell * cell)
    filled = dens[dens > 0]
    stats = {
        "density_cell_m": float(cell),
        "density_median": float(np.median(filled)) if filled.size else 0.0,
        "density_p05": float(np.percentile(filled, 5)) if filled.size else 0.0,
        "empty_cells_pct": float(100.0 * (dens == 0).mean()),
    }
    return dens, stats


# --------------------------------------------------------------------------- the data edge
def data_extent(boxes: Iterable[Sequence[float]]) -> Any:
    """The area the points of a block's towers can come from: the union of block boxes.

    ``boxes`` are ``(xmin, ymin, xmax, ymax)`` of the block and of every neighbour that
    gave points (a neighbour that could not be read is left out, so a tower reaching
    into it counts as cut). Boxes are grown by :data:`SEAM_TOLERANCE_M` so that two
    adjoining blocks join without a slit along their seam.
    """
    import shapely

    polys = [shapely.box(*b).buffer(SEAM_TOLERANCE_M, join_style="mitre") for b in boxes if b is not None]
    return shapely.union_all(polys) if polys else None


def distance_to_data_edge(footprint: Any, extent: Any) -> float:
    """Distance (m) from a tower footprint to the edge of the data; 0 when it reaches it.

    A tower across a seam between two blocks that both gave points is whole: its
    footprint is far from the edge of their union even though its centroid is near the
    seam. A tower at the edge of the zone, or next to a block that failed, is not.
    """
    if extent is None or footprint is None or footprint.is_empty:
        return float("nan")
    if not extent.contains(footprint):
        return 0.0
    return float(extent.boundary.distance(footprint))


# --------------------------------------------------------------------------- accuracy
def _neighbour_frame(neighbour_towers: Sequence[Mapping[str, Any]] | None, crs: Any) -> Any:
    """The towers with points in a block that a neighbour reports (``tower_id``,
    ``footprint_wkt``) as a GeoDataFrame of ``tower_id`` (text) and footprints."""
    import geopandas as gpd
    import shapely

    towers = neighbour_towers or []
    return gpd.GeoDataFrame(
        {"tower_id": [str(t["tower_id"]) for t in towers]},
        geometry=shapely.from_wkt([t["footprint_wkt"] for t in towers]),
        crs=crs,
    )


def with_neighbour_towers(
    m: dict[str, Any], truth: Any, neighbour_towers: Sequence[Mapping[str, Any]]
) -> dict[str, Any]:
    """Recall counting labelled towers matched by a neighbour-owned tower as found."""
    from towerpipe.towers.matching import f1_score, match_towers

    nb = _neighbour_frame(neighbour_towers, truth.crs)
    left = truth[truth["tower_id"].astype(str).isin(m["unmatched_truth"])]
    extra = match_towers(nb, left, max_dist=5.0)["matches"] if len(left) else []
    found = {x["truth"] for x in extra}
    tp_recall = m["tp"] + len(extra)
    m = dict(
        m,
        fn=len(truth) - tp_recall,
        recall=tp_recall / len(truth),
        matches=[*m["matches"], *({**x, "owner": "neighbour"} for x in extra)],
        unmatched_truth=[t for t in m["unmatched_truth"] if t not in found],
    )
    m["f1"] = f1_score(m["precision"], m["recall"])
    return m


def with_towers_across_the_seam(
    m: dict[str, Any],
    towers: Any,
    across: Any,
    bounds: Sequence[float],
    neighbour_towers: Sequence[Mapping[str, Any]] | None = None,
) -> dict[str, Any]:
    """Precision counting as found a tower this block reports whose labelled tower has its
    centroid in a neighbouring block.

    The two centroids of a tower on the seam may lie on either side of it. Only a tower whose
    footprint crosses the block's edge is credited: the neighbour then lists it among the towers
    with points in that block that this one reports, and counts the labelled tower as found with
    it (:func:`with_neighbour_towers`), so the pair counts once in the zone's sums. This block's
    unmatched towers and ``neighbour_towers`` are matched to ``across`` one to one, together: a
    labelled tower the segmenter split in two, a part reported here and a part by the
    neighbour, is credited to one of them.

    Parameters
    ----------
    m
        :func:`towerpipe.towers.matching.match_towers` of ``towers`` against the labelled towers
        whose centroid lies in ``bounds`` (after :func:`with_neighbour_towers`).
    towers
        The towers this block reports.
    across
        The labelled towers whose centroid lies outside ``bounds``.
    bounds
        The block's bounds.
    neighbour_towers
        The towers with points in this block that a neighbour reports (``tower_id``,
        ``footprint_wkt``).

    Returns
    -------
    dict
        ``m`` with ``tp``, ``fp``, ``precision``, ``f1``, ``matches`` (a credited one with
        ``"owner": "labelled across the seam"``) and ``unmatched_pred`` updated; ``tp`` counts
        the block's towers that match a labelled tower.
    """
    import pandas as pd
    import shapely

    from towerpipe.towers.matching import f1_score, match_towers

    left = set(m["unmatched_pred"])
    crossing = ~towers.geometry.within(shapely.box(*bounds)).to_numpy()
    mine = towers[towers["tower_id"].astype(str).isin(left).to_numpy() & crossing][["tower_id", "geometry"]]
    if not len(mine):
        return m
    others = _neighbour_frame(neighbour_towers, towers.crs)
    cands = pd.concat([mine.assign(tower_id=mine["tower_id"].astype(str)), others], ignore_index=True)
    ours = set(mine["tower_id"].astype(str))
    extra = [x for x in match_towers(cands, across, max_dist=5.0)["matches"] if x["pred"] in ours]
    if not extra:
        return m
    found = {x["pred"] for x in extra}
    fp = m["fp"] - len(extra)
    m = dict(
        m,
        tp=m["tp"] + len(extra),
        fp=fp,
        precision=(len(towers) - fp) / len(towers),
        matches=[*m["matches"], *({**x, "owner": "labelled across the seam"} for x in extra)],
        unmatched_pred=[t for t in m["unmatched_pred"] if t not in found],
    )
    m["f1"] = f1_score(m["precision"], m["recall"])
    return m


def label_accuracy(
    pts: Mapping[str, np.ndarray],
    truth: np.ndarray,
    towers: Any,
    bounds: Sequence[float] | None,
    *,
    min_truth_points: int,
    mast_prominence: float = 0.0,
    neighbour_towers: Sequence[Mapping[str, Any]] | None = None,
    truth_points: Mapping[str, np.ndarray] | None = None,
) -> dict[str, Any] | None:
    """Tower precision/recall and point IoU against the input's class 15 labels (None without any).

    The point IoU is over the block's points. The labelled towers are built from
    ``truth_points`` (``x, y, z, hag`` of the labelled points of the block's tiles, core and
    buffer: :func:`towerpipe.io.tiles.labelled_points`) when given, else from the block's
    labelled points; those whose centroid lies in ``bounds`` count. From the tiles, a tower on
    the seam of two blocks is whole, so it counts in the one block that holds its centroid;
    from the block's points alone each block would count its half. A tower this block reports
    across the seam that matches a labelled tower whose centroid lies in the neighbour is not
    false (:func:`with_towers_across_the_seam`); the neighbour counts that labelled tower as found
    (``neighbour_towers``).
    """
    # the tower matching (scipy's graphs and trees) only for a block with labels to check
    from towerpipe.towers.matching import match_towers, towers_from_labels

    truth = np.asarray(truth)
    t_mask = truth.astype(bool) if truth.dtype == bool else truth == classes.TOWER
    if len(t_mask) != len(pts["x"]):
        raise ValueError(f"truth has {len(t_mask)} labels for {len(pts['x'])} points")
    if not t_mask.any():
        return None
    p_mask = pts["classification"] == classes.TOWER
    inter = int(np.count_nonzero(p_mask & t_mask))
    union = int(np.count_nonzero(p_mask | t_mask))
    # labelled towers are clustered as the tower rules cluster (two towers whose crossarms touch: two)
    split = {"min_points": int(min_truth_points), "mast_prominence": float(mast_prominence)}
    if truth_points is not None:
        tp = truth_points
        true_towers = towers_from_labels(tp["x"], tp["y"], tp["z"], tp.get("hag"), np.ones(len(tp["x"]), bool), **split)
    else:
        true_towers = towers_from_labels(pts["x"], pts["y"], pts["z"], pts.get("hag"), t_mask, **split)
    across = true_towers.iloc[:0]
    if bounds is not None and len(true_towers):
        c = true_towers.geometry.centroid
        inside = ((c.x >= bounds[0]) & (c.x < bounds[2]) & (c.y >= bounds[1]) & (c.y < bounds[3])).to_numpy()
        true_towers, across = true_towers[inside], true_towers[~inside]
    m = match_towers(towers, true_towers, max_dist=5.0)
    if neighbour_towers and len(true_towers):
        m = with_neighbour_towers(m, true_towers, neighbour_towers)
    if m["unmatched_pred"] and len(across):
        m = with_towers_across_the_seam(m, towers, across, bounds, neighbour_towers)
    return {
        "point_iou": inter / union if union else None,
        "points_true": int(t_mask.sum()),
        "points_pred": int(p_mask.sum()),
        "points_both": inter,
        "towers_true": int(len(true_towers)),
        **{k: m[k] for k in ("precision", "recall", "f1", "tp", "fp", "fn", "matches")},
    }
