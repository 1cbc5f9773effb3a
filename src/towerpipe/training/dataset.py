"""Training windows from labelled tile files (Carós et al. 2022, sec. 4 and 5.1).

For each tile (``towerpipe.io.tiles``) only the ``model_input`` points are used:

* towers = connected components of class-15 points (``cKDTree`` pairs within
  ``tower_link_m``), kept when they have at least ``min_tower_points`` points and
  their centroid lies in the tile's core (so a tower is taken once per zone);
* positive windows (``window_size`` square, all points) centred on each tower, plus
  ``positive_shifts`` copies with the centre shifted by up to ``shift_m`` in x and y (the
  paper's augmentation);
* a *hard negative* per positive: the same window with every tower point removed;
* negatives: random centres in the tile core, and tall negatives. Half of the tall budget goes to the
  tallest *objects* of the tile (:func:`tall_objects`: connected groups of tall, HAG >= ``tall_hag_m``,
  non-tower points), two windows each as for a positive: centred on its highest point and shifted by
  up to ``shift_m``. These are cranes, masts, turbines, chimneys, the tallest trees: the rare things a
  classifier confuses with pylons. The rest is centred on tall points drawn at random, at least half a
  window apart (mostly trees and wires: what the height pre-filter sends to the classifier). A
  candidate holding a tower is rejected. With
  ``peak_negatives_per_tile``, more tall negatives are centred on the tile's height peaks,
  where candidate windows (:func:`towerpipe.inference.candidates.candidate_windows`) put them at inference.

Variety aimed at real flights (``density_range``, ``occlusion``): each window is thinned to its own
density, drawn log-uniformly in ``density_range`` (pts/m², all returns; a window cannot be denser than
its zone), so one tower is seen at 2 and at 30 pts/m²; a positive keeps at least ``min_tower_points`` + 10 of its tower's points. With probability
``occlusion`` a positive's tower also loses most of the points of one side (a face in scan
shadow): those beyond a random vertical plane through its centre are kept with a chance
drawn in 0-0.4. ``tower_thinning`` (``{"probability": p, "keep": [lo, hi]}``, off by default) keeps, with
probability ``p``, a rate log-uniform in ``[lo, hi]`` of a window's tower points (at least ``min_tower_points`` + 10).

Real tower families: with the zones' truth (``truth``, :func:`build_windows`), every
window records which families (:data:`towerpipe.training.windowset.FAMILY_BITS`) its tower
points come from, and a hard negative the family of the tower it lost, so that training can
leave one family out (``exclude_families`` in :mod:`towerpipe.training.train`).

The built windows are a :class:`towerpipe.training.windowset.WindowSet`. A window is positive
when it holds at least ``min_tower_points`` tower points. The split is *by block* (the block of
the tile whose core holds the window centre), so no block contributes to two splits; blocks with
towers are split separately from the others.

Each window stores its point pool as float16 features (:data:`towerpipe.model.features.ALL_FEATURES`;
the local structure taken among all its points) with per-point labels, plus the indices of its
constrained and random 2048-point samples into the pool. Positive windows keep *all* their points
(segmentation is evaluated on every point, as at inference); other windows keep both samples.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from towerpipe import classes
from towerpipe.errors import ConfigError
from towerpipe.inference.candidates import height_peaks
from towerpipe.io.columns import read_meta
from towerpipe.io.tiles import load_tile
from towerpipe.model.features import ALL_FEATURES, compute_columns, tile_feature_meta
from towerpipe.model.sampling import constrained_sample, random_sample
from towerpipe.preprocess.attributes import valid_everywhere
from towerpipe.training.windowset import FAMILY_BITS, KINDS, SPLITS, WindowSet, is_windows_file, load_windows, summarise

log = logging.getLogger(__name__)

DEFAULT_DATASET_CONFIG: dict[str, Any] = {
    "seed": 0,
    "n_points": 2048,
    "bands": [3.0, 8.0],
    "window_size": 40.0,
    "tower_class": classes.TOWER,
    "tower_link_m": 2.5,
    "min_tower_points": 20,
    "shift_m": 10.0,
    "random_negatives_per_tile": 6,
    "tall_negatives_per_tile": 3,
    "tall_hag_m": 10.0,
    "tall_object_cell_m": 2.0,
    "min_window_points": 16,
    "val_fraction": 0.15,
    "test_fraction": 0.15,
    "split": None,
    "peak_negatives_per_tile": 0,
    "positive_shifts": 1,
    "density_range": None,
    "occlusion": 0.0,
    "tower_thinning": None,
}


def dataset_config(config: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Defaults updated with ``config`` (unknown keys rejected with :class:`ConfigError`)."""
    out = dict(DEFAULT_DATASET_CONFIG)
    for k, v in (config or {}).items():
        if k not in out:
            raise ConfigError(f"dataset config: unknown key {k!r}; known: {sorted(out)}")
        out[k] = v
    return out


def tower_instances(xyz: np.ndarray, link: float, min_points: int) -> list[np.ndarray]:
    """Connected components of points within ``link`` metres, with at least ``min_points``.

    Parameters
    ----------
    xyz
        ``(m, 3)`` coordinates of the tower-class points.
    link
        Linkage distance (m).
    min_points
        Smaller components are dropped.

    Returns
    -------
    list of numpy.ndarray
        Index arrays into ``xyz``, one per tower, ordered by smallest index.
    """
    m = len(xyz)
    if m == 0:
        return []
    pairs = cKDTree(xyz).query_pairs(link, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1]))
        if len(pairs)
        else (np.zeros(0), (np.zeros(0, int), np.zeros(0, int))),
        shape=(m, m),
    )
    _, lab = connected_components(graph, directed=False)
    comps = [np.flatnonzero(lab == c) for c in np.unique(lab)]
    return sorted([c for c in comps if c.size >= min_points], key=lambda c: int(c[0]))


def tall_objects(xy: np.ndarray, hag: np.ndarray, cell: float) -> list[tuple[np.ndarray, float]]:
    """Tall objects: 8-connected groups of occupied ``cell`` squares of tall points.

    Parameters
    ----------
    xy
        ``(m, 2)`` coordinates of the tall non-tower points.
    hag
        ``(m,)`` their heights above ground.
    cell
        Grid cell (m); points in touching cells belong to one object.

    Returns
    -------
    list of (numpy.ndarray, float)
        ``(xy of the object's highest point, its HAG)``, tallest object first.
    """
    from scipy import ndimage

    if len(xy) == 0:
        return []
    ij = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64)
    grid = np.zeros(tuple(ij.max(axis=0) + 1), dtype=bool)
    grid[ij[:, 0], ij[:, 1]] = True
    labels, n = ndimage.label(grid, structure=np.ones((3, 3), bool))
    obj = labels[ij[:, 0], ij[:, 1]] - 1
    order = np.lexsort((-hag, obj))  # per object, highest point first
    first = order[np.r_[True, obj[order][1:] != obj[order][:-1]]]
    first = first[np.argsort(-hag[first], kind="stable")]
    return [(xy[i].copy(), float(hag[i])) for i in first]


def split_blocks(
    has_towers: Mapping[str, bool], val_fraction: float, test_fraction: float, seed: int
) -> dict[str, str]:
    """Assign each block to ``train``/``val``/``test``, stratified by whether it has towers.

    Blocks with towers: at least one each in val and test (needs >= 3 such blocks).

    Returns
    -------
    dict
        block name -> split name.
    """
    rng = np.random.default_rng(seed)
    tower = sorted(b for b, t in has_towers.items() if t)
    other = sorted(b for b, t in has_towers.items() if not t)
    if len(tower) < 3:
        raise ConfigError(
            f"dataset: a block split needs >= 3 blocks with towers, got {len(tower)} "
            f"({tower}); use a larger zone or set `training: {{dataset: {{split: {{val: [...], test: [...]}}}}}}`"
        )
    out: dict[str, str] = {}
    for group, need in ((tower, True), (other, False)):
        order = [group[i] for i in rng.permutation(len(group))]
        n_val = int(round(val_fraction * len(order)))
        n_test = int(round(test_fraction * len(order)))
        if need:
            n_val, n_test = max(1, n_val), max(1, n_test)
        while n_val + n_test >= len(order) and (n_val + n_test) > 0 and len(order) > 0:
            if n_val >= n_test and n_val > (1 if need else 0):
                n_val -= 1
            elif n_test > (1 if need else 0):
                n_test -= 1
            else:
                break
        for i, b in enumerate(order):
            out[b] = "test" if i < n_test else "val" if i < n_test + n_val else "train"
    return out


def nearest_families(xy: np.ndarray, truth: Any) -> np.ndarray:
    """Family name (a key of :data:`FAMILY_BITS`) of the true tower nearest each ``(n, 2)`` xy:
    its real family, else ``"synthetic"`` (also for every point without a truth)."""
    from towerpipe.synth.real import tower_family

    if truth is None or len(truth) == 0 or len(xy) == 0:
        return np.full(len(xy), "synthetic", dtype=object)
    names = np.array([tower_family(d) or "synthetic" for d in truth["design"]], dtype=object)
    _, i = cKDTree(np.c_[truth["x"], truth["y"]]).query(xy)
    return names[i]


def _point_families(xy: np.ndarray, truth: Any) -> np.ndarray:
    """Family bit (:data:`FAMILY_BITS`) of tower points: that of the nearest true tower (0 without a truth)."""
    if truth is None or len(truth) == 0 or len(xy) == 0:
        return np.zeros(len(xy), np.uint8)
    return np.array([FAMILY_BITS[f] for f in nearest_families(xy, truth)], np.uint8)


def _tile_windows(path: str, cfg: Mapping[str, Any], rng: np.random.Generator, truth: Any = None) -> dict[str, Any]:
    """Windows of one tile: dict of lists (centres, pools, samples, labels, kinds, families)."""
    tile = load_tile(path)
    meta = tile.meta
    mi = tile["model_input"]
    arr = {k: v[mi] for k, v in tile.arrays.items()}
    fmeta = tile_feature_meta(tile.arrays, meta)
    n_pts = int(cfg["n_points"])
    half = float(cfg["window_size"]) / 2.0
    xmin, ymin, xmax, ymax = [float(v) for v in meta["core_bounds"]]
    # density of all returns of the tile's core (what a flight's pts/m² counts)
    zone_density = float(np.asarray(tile["core"]).sum()) / max((xmax - xmin) * (ymax - ymin), 1.0)
    out: dict[str, list[Any]] = {k: [] for k in ("center", "feat", "plabel", "cs", "rs", "label", "kind", "family")}
    counts = {"towers": 0, "towers_dropped": 0, "tall_objects": 0}
    if len(arr["x"]) == 0:
        return {"out": out, "counts": counts, "block": meta.get("block", Path(path).parent.name), "meta": meta}
    xy = np.column_stack([arr["x"], arr["y"]])
    tree = cKDTree(xy)
    is_tower = arr["classification"] == int(cfg["tower_class"])
    tidx = np.flatnonzero(is_tower)
    xyz = np.column_stack([arr["x"][tidx], arr["y"][tidx], arr["z"][tidx]])
    all_comps = tower_instances(xyz, float(cfg["tower_link_m"]), 1)
    comps = [c for c in all_comps if c.size >= int(cfg["min_tower_points"])]
    counts["towers_dropped"] = len(all_comps) - len(comps)
    bands = tuple(float(b) for b in cfg["bands"])
    family = np.zeros(len(arr["x"]), np.uint8)
    family[tidx] = _point_families(xy[tidx], truth)
    min_tower = int(cfg["min_tower_points"])
    dens_range = cfg["density_range"]

    def thin(pts: np.ndarray, towers_kept: int) -> np.ndarray:
        """The window's points at its own density (see the module docstring)."""
        if not dens_range:
            return pts
        lo, hi = (float(v) for v in dens_range)
        keep = min(1.0, float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) / max(zone_density, 1e-9))
        if towers_kept:
            keep = max(keep, min(1.0, (min_tower + 10) / towers_kept))
        return pts if keep >= 1.0 else pts[rng.random(pts.size) < keep]

    def thin_tower(pts: np.ndarray) -> np.ndarray:
        """The tower's points sparser than the rest of the window (see the module docstring)."""
        spec = cfg["tower_thinning"]
        if not spec or rng.random() >= float(spec["probability"]):
            return pts
        tw = np.flatnonzero(is_tower[pts])
        rate = float(np.exp(rng.uniform(*np.log(np.asarray(spec["keep"], float)))))
        kept = rng.choice(tw, min(tw.size, max(round(rate * tw.size), min_tower + 10)), replace=False)
        return np.delete(pts, np.setdiff1d(tw, kept))

    def occlude(pts: np.ndarray, tower_c: np.ndarray) -> np.ndarray:
        """A face of the tower in scan shadow (see the module docstring)."""
        if tower_c is None or not cfg["occlusion"] or rng.random() >= float(cfg["occlusion"]):
            return pts
        a = rng.uniform(0, 2 * np.pi)
        side = ((xy[pts] - tower_c) @ np.array([np.cos(a), np.sin(a)])) > 0
        gone = is_tower[pts] & side & (rng.random(pts.size) >= rng.uniform(0.0, 0.4))
        return pts[~gone] if is_tower[pts][~gone].sum() >= min_tower + 10 else pts

    def add(center: np.ndarray, kind: str, drop_towers: bool = False, tower_c: np.ndarray | None = None) -> bool:
        pts = np.asarray(tree.query_ball_point(center, half, p=np.inf), dtype=np.int64)
        fam = int(np.bitwise_or.reduce(family[pts])) if pts.size else 0
        if drop_towers:
            pts = pts[~is_tower[pts]]
        pts = occlude(thin_tower(thin(pts, int(is_tower[pts].sum()))), tower_c)
        pts.sort()
        if pts.size < int(cfg["min_window_points"]):
            return False
        label = int(is_tower[pts].sum() >= min_tower)
        if kind in ("random_negative", "tall_negative") and is_tower[pts].any():
            return False
        cs = constrained_sample(arr["hag"][pts], n_pts, rng, bands)
        rs = random_sample(pts.size, n_pts, rng)
        if label:
            pool = np.arange(pts.size)
        else:
            pool = np.union1d(cs, rs)
            cs = np.searchsorted(pool, cs)
            rs = np.searchsorted(pool, rs)
        sel = pts[pool]
        out["center"].append(center.copy())
        out["feat"].append(compute_columns(arr, pts, tuple(center[:2]), ALL_FEATURES, fmeta, pool).astype(np.float16))
        out["plabel"].append(is_tower[sel].astype(np.uint8))
        out["cs"].append(cs.astype(np.int32))
        out["rs"].append(rs.astype(np.int32))
        out["label"].append(label)
        out["kind"].append(KINDS[kind])
        out["family"].append(fam)
        return True

    for c in comps:
        cen = xy[tidx[c]].mean(axis=0)
        if not (xmin <= cen[0] < xmax and ymin <= cen[1] < ymax):
            continue
        counts["towers"] += 1
        centres = [(cen, "positive")] + [
            (cen + rng.uniform(-float(cfg["shift_m"]), float(cfg["shift_m"]), size=2), "positive_shifted")
            for _ in range(int(cfg["positive_shifts"]))
        ]
        for centre, kind in centres:
            if add(centre, kind, tower_c=cen):
                add(centre, "hard_negative", drop_towers=True)
    n_rand = int(cfg["random_negatives_per_tile"])
    for _ in range(n_rand * 5):
        if sum(1 for k in out["kind"] if k == KINDS["random_negative"]) >= n_rand:
            break
        add(np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)]), "random_negative")
    tall = np.flatnonzero(
        (arr["hag"] >= float(cfg["tall_hag_m"]))
        & ~is_tower
        & (xy[:, 0] >= xmin)
        & (xy[:, 0] < xmax)
        & (xy[:, 1] >= ymin)
        & (xy[:, 1] < ymax)
    )
    objects = tall_objects(xy[tall], arr["hag"][tall], float(cfg["tall_object_cell_m"]))
    counts["tall_objects"] = len(objects)
    n_tall = int(cfg["tall_negatives_per_tile"])
    shift = float(cfg["shift_m"]) / 2.0
    chosen: list[np.ndarray] = []

    def add_tall(centre: np.ndarray) -> None:
        if add(centre, "tall_negative"):
            chosen.append(centre)

    for top, _ in objects[: 3 * n_tall]:  # the tallest objects of the tile
        if len(chosen) >= (n_tall + 1) // 2:
            break
        # centred on the top and shifted, like a positive (rejected where it holds a tower)
        for centre in (top, top + rng.uniform(-2 * shift, 2 * shift, size=2)):
            add_tall(centre)
    for j in rng.permutation(tall)[: n_tall * 20]:  # then tall points, one window per 20 m
        if len(chosen) >= n_tall:
            break
        if not chosen or np.min(np.abs(np.asarray(chosen) - xy[j]).max(axis=1)) >= half:
            add_tall(xy[j].copy())
    n_peak = int(cfg["peak_negatives_per_tile"])
    if n_peak:  # windows as inference lays them: on the height peaks (not towers)
        _, peaks, _ = height_peaks(xy[:, 0], xy[:, 1], arr["hag"], min_height=float(cfg["tall_hag_m"]))
        inside = (peaks[:, 0] >= xmin) & (peaks[:, 0] < xmax) & (peaks[:, 1] >= ymin) & (peaks[:, 1] < ymax)
        added = 0
        for centre in peaks[inside][rng.permutation(int(inside.sum()))]:
            if added >= n_peak:
                break
            added += add(centre, "tall_negative")
    return {"out": out, "counts": counts, "block": meta.get("block", Path(path).parent.name), "meta": meta}


def build_windows(
    tile_paths: Iterable[str | os.PathLike[str]],
    config: Mapping[str, Any] | None = None,
    out_path: str | os.PathLike[str] | None = None,
    truth: Mapping[str, str | os.PathLike[str]] | None = None,
) -> WindowSet:
    """Build training windows from labelled tile files.

    Parameters
    ----------
    tile_paths
        Tile ``.npz`` files (``towerpipe.io.tiles``) with classification labels.
    config
        Overrides of :data:`DEFAULT_DATASET_CONFIG`.
    out_path
        If given, the windows are also saved there.
    truth
        Zone name -> its tower truth GeoPackage (``towers_truth.gpkg`` of a generated
        zone): gives each window its tower families (``family``). Zones not listed: 0.

    Returns
    -------
    WindowSet
    """
    cfg = dataset_config(config)
    paths = sorted(str(p) for p in tile_paths)
    if not paths:
        raise ConfigError("dataset: no tile files given")
    truths = {z: read_truth(t) for z, t in (truth or {}).items()}
    rng = np.random.default_rng(int(cfg["seed"]))
    per_tile = []
    for p in paths:
        zone = read_meta(p).get("zone")
        r = _tile_windows(p, cfg, np.random.default_rng([int(cfg["seed"]), len(per_tile)]), truths.get(zone))
        per_tile.append(r)
        log.info("%s: %d windows, %d towers", p, len(r["out"]["label"]), r["counts"]["towers"])
    blocks = sorted({r["block"] for r in per_tile})
    has_towers = {b: False for b in blocks}
    for r in per_tile:
        has_towers[r["block"]] |= any(r["out"]["label"])
    if cfg["split"]:
        sp = cfg["split"]
        unknown = sorted(str(b) for k in ("val", "test") for b in sp.get(k, []) if str(b) not in blocks)
        if unknown or set(sp) - {"val", "test"}:
            raise ConfigError(
                f"dataset split: blocks {unknown} are not among the tiles' blocks {blocks} (or keys "
                f"other than val/test); quote block names in YAML (400000_4600800 is a number there)"
            )
        assign = {
            b: "test" if b in sp.get("test", []) else "val" if b in sp.get("val", []) else "train" for b in blocks
        }
    else:
        assign = split_blocks(
            has_towers, float(cfg["val_fraction"]), float(cfg["test_fraction"]), int(rng.integers(1 << 31))
        )
    feats, plabels, cs, rs, label, kind, split, block_id, center, sizes, fams = ([] for _ in range(11))
    for r in per_tile:
        o = r["out"]
        b = blocks.index(r["block"])
        for f, pl, c, s, lab, k, cen, fm in zip(
            o["feat"], o["plabel"], o["cs"], o["rs"], o["label"], o["kind"], o["center"], o["family"]
        ):
            feats.append(f)
            plabels.append(pl)
            cs.append(c)
            rs.append(s)
            label.append(lab)
            kind.append(k)
            split.append(SPLITS[assign[r["block"]]])
            block_id.append(b)
            center.append(cen)
            sizes.append(len(pl))
            fams.append(fm)
    if not label:
        raise ConfigError(f"dataset: no windows could be built from {len(paths)} tile files (no model-input points?)")
    n = int(cfg["n_points"])
    ws = WindowSet(
        feat=np.concatenate(feats),
        point_label=np.concatenate(plabels),
        offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        cs_idx=np.stack(cs).reshape(-1, n),
        rs_idx=np.stack(rs).reshape(-1, n),
        label=np.asarray(label, np.uint8),
        kind=np.asarray(kind, np.uint8),
        split=np.asarray(split, np.uint8),
        block_id=np.asarray(block_id, np.int32),
        center=np.asarray(center, np.float64).reshape(-1, 2),
        family=np.asarray(fams, np.uint8),
        meta={
            "config": cfg,
            "blocks": blocks,
            "split": assign,
            "tiles": paths,
            "has_rgb": all(bool(r["meta"].get("has_rgb", False)) for r in per_tile),
            "has_nir": all(bool(r["meta"].get("has_nir", False)) for r in per_tile),
            "valid_attributes": valid_everywhere([r["meta"] for r in per_tile]),
            "towers": int(sum(r["counts"]["towers"] for r in per_tile)),
            "towers_dropped_small": int(sum(r["counts"]["towers_dropped"] for r in per_tile)),
            "tall_objects": int(sum(r["counts"]["tall_objects"] for r in per_tile)),
            "features": ALL_FEATURES,
        },
    )
    ws.meta["summary"] = summarise(ws)
    if out_path is not None:
        ws.save(out_path)
    return ws


def read_truth(path: str | os.PathLike[str]) -> Any:
    """The ``design``, ``x`` and ``y`` of the towers of a zone's truth GeoPackage (layer ``towers``)."""
    import pyogrio

    return pyogrio.read_dataframe(path, layer="towers", columns=["design", "x", "y"], read_geometry=False)


def load_or_build(
    paths: Sequence[str | os.PathLike[str]] | str | os.PathLike[str], config: Mapping[str, Any] | None = None
) -> WindowSet:
    """A :class:`WindowSet` from one windows file, or built from tile files."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    paths = [str(p) for p in paths]
    if len(paths) == 1 and is_windows_file(paths[0]):
        return load_windows(paths[0])
    return build_windows(paths, config)
