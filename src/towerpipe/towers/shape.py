"""The shape check of a tower: does the object under a candidate look like a tower or a tree?

The segmenter decides point by point inside a 40 m window; in woodland it paints crowns of
10-20 m trees as tower points, and the confident-core rule that held those back also drops
real towers the segmenter is unsure of. The shape check looks at the *object* instead: the
model-input points (heights above ground) inside a candidate's footprint buffered by
:data:`OBJECT_BUFFER_M`, described by a few numbers that a lattice tower and a tree crown
do not share (:func:`shape_descriptor`): how the points spread over height (a tower is seen
from the ground to its top, a crown is a cap), how wide each height band is against the
height, how filled the plan view is (a crown is a closed canopy, a lattice is open), and the
principal axes. The numbers are taken on a 0.5 m voxel grid, so a flight's density barely
moves them, and read no attribute but position: every delivery has them.

A small network (:class:`ShapeVerifier`, two hidden layers, numpy at inference: the towers
job never loads PyTorch) turns the descriptor into a *shape score* in [0, 1]; it is trained
by :mod:`towerpipe.training.verifier` on the objects of the training zones (true towers,
real and generated, against trees, buildings, cranes and masts at height peaks) and shipped
as ``models/towerpipe-verifier-v<N>`` with its card. :func:`towerpipe.towers.extract.extract_towers`
records each tower's score and drops those below ``towers.min_shape_score``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from towerpipe.towers.hull import plan_hull

__all__ = [
    "DESCRIPTOR_NAMES",
    "OBJECT_BUFFER_M",
    "PEAK_CORE_RADIUS",
    "PEAK_OBJECT_MIN_HAG",
    "PEAK_OBJECT_RADIUS",
    "SHAPE_VIEWS",
    "VERIFIER_FILE",
    "VERIFIER_RELEASE",
    "ShapeVerifier",
    "core_object",
    "load_verifier",
    "object_points",
    "peak_objects",
    "peak_scores",
    "resolve_verifier",
    "shape_descriptor",
]

#: Release of the shipped shape verifier (``models/towerpipe-verifier-v<N>``).
VERIFIER_RELEASE = 2
#: The verifier's weights and normalisation, in its directory.
VERIFIER_FILE = "verifier.json"
#: Voxel edge (m) the descriptor is computed on: density-robust, a tower member is ~0.2-0.5 m.
VOXEL_M = 0.5
#: The object of a tower candidate: model-input points within this distance (m) of its footprint.
OBJECT_BUFFER_M = 1.0
#: The object at a height peak (:func:`peak_objects`): the points at least
#: :data:`PEAK_OBJECT_MIN_HAG` m high within :data:`PEAK_OBJECT_RADIUS` m of the peak, as
#: the verifier's negatives are cut (2.5-8 m, :mod:`towerpipe.training.verifier`). 5 m keeps a
#: lattice tower's body and most of its crossarms: of the calibration zones' candidates
#: within 6 m of a true tower, none scores below 0.05 that a tower found today stands on
#: (4 m cut the body of two generated towers, 6 m and 8 m took in crowns beside real ones).
PEAK_OBJECT_RADIUS, PEAK_OBJECT_MIN_HAG = 5.0, 2.0
#: The *core* of an object (:func:`core_object`), cut as :func:`peak_objects` cuts it but within
#: this radius (m) of its top: a tower standing among crowns. Around a sparse lattice the crowns
#: can hold 10-50 times its points and its object scores as a canopy; within 3 m the lattice
#: still holds its share. The shape check judges a cluster that fails with no part to judge by
#: it (:func:`towerpipe.towers.shape_check.shape_check`); 3 m was set on the calibration zones
#: against 2.5 and 4 m (docs/model.md, "The core of an object").
PEAK_CORE_RADIUS = 3.0
#: What a tower's shape score judged (its record's ``shape_view``): its object
#: (:func:`object_points`), or the core of that object (:func:`core_object`).
SHAPE_VIEWS = ("object", "core")
#: Height bands (shares of the object's height) of the descriptor.
N_BANDS = 5

#: Names of the descriptor's entries, in order.
DESCRIPTOR_NAMES: tuple[str, ...] = (
    ("log_height", "base_ratio")
    + tuple(f"band{i}_share" for i in range(N_BANDS))
    + tuple(f"band{i}_radius_rel" for i in range(N_BANDS))
    + tuple(f"band{i}_log_radius" for i in range(N_BANDS))
    + (
        "log_plan_major",
        "plan_minor_major",
        "linearity",
        "planarity",
        "scattering",
        "verticality",
        "height_continuity",
        "largest_gap_rel",
        "column_fill",
        "log_columns",
        "plan_fill",
        "log_plan_area",
        "top_vs_middle_radius",
    )
)


def unique_rows(cells: np.ndarray) -> np.ndarray:
    """``np.unique(cells, axis=0)`` of ``(n, k)`` integer cells, through one integer key per row.

    The rows come out in the same lexicographic order (so every sum over them rounds as
    before), at a fraction of the cost of NumPy's row-wise unique (a structured sort).
    """
    cells = np.asarray(cells, np.int64)
    if len(cells) == 0:
        return cells.reshape(0, cells.shape[1])
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0**62:  # no key fits in int64: NumPy's way
        return np.unique(cells, axis=0)
    # mixed radix, the first column most significant: keys sort as the rows do
    weights = np.cumprod(np.r_[span[1:], 1][::-1])[::-1]
    keys = np.unique((cells - lo) @ weights)
    out = np.empty((len(keys), cells.shape[1]), np.int64)
    for j, w in enumerate(weights):
        out[:, j], keys = np.divmod(keys, w)
    return out + lo


def shape_descriptor(x: np.ndarray, y: np.ndarray, hag: np.ndarray) -> np.ndarray:
    """The shape descriptor of one object (:data:`DESCRIPTOR_NAMES`).

    Parameters
    ----------
    x, y
        Plan coordinates (m); any offset (only differences are used).
    hag
        Heights above ground (m).

    Returns
    -------
    numpy.ndarray
        ``(len(DESCRIPTOR_NAMES),)`` float64; invariant to a shift and a rotation about the
        vertical, and nearly to the point density (computed on occupied voxels).
    """
    x, y, hag = (np.asarray(a, np.float64) for a in (x, y, hag))
    if len(x) == 0:
        raise ValueError("shape_descriptor: an object without points")
    pts = np.c_[x - x.mean(), y - y.mean(), hag]
    vox = unique_rows(np.floor(pts / VOXEL_M).astype(np.int64))
    q = (vox + 0.5) * VOXEL_M
    height = max(float(hag.max()), 1.0)
    rel = np.clip(q[:, 2] / height, 0.0, 1.0 - 1e-9)
    d = q[:, :2] - q[:, :2].mean(axis=0)
    radius = np.hypot(d[:, 0], d[:, 1])
    band = (rel * N_BANDS).astype(int)
    n_band = np.bincount(band, minlength=N_BANDS)
    share = n_band / len(q)
    rms = np.sqrt(np.bincount(band, radius**2, minlength=N_BANDS) / np.maximum(n_band, 1))
    plan = np.linalg.eigvalsh(np.cov(d.T)) if len(q) > 2 else np.full(2, 1e-3)
    major, minor = np.sqrt(np.clip(plan[::-1], 1e-6, None))
    if len(q) > 3:
        ev, vec = np.linalg.eigh(np.cov((q - q.mean(axis=0)).T))
        ev, vec = np.clip(ev[::-1], 1e-9, None), vec[:, ::-1]
    else:
        ev, vec = np.array([1.0, 1e-9, 1e-9]), np.eye(3)[:, ::-1]
    slices = np.unique(np.floor(q[:, 2]).astype(np.int64))
    gaps = np.diff(np.sort(np.r_[0.0, q[:, 2], height]))
    columns = unique_rows(vox[:, :2])
    # the plan hull of the voxels is that of their columns (a column's voxels share its centre)
    hull = plan_hull((columns + 0.5) * VOXEL_M)
    area = max(float(hull.area), VOXEL_M * VOXEL_M)
    top, middle = rel >= 0.8, (rel >= 0.3) & (rel < 0.7)
    r_top = np.sqrt(np.mean(radius[top] ** 2)) if top.any() else 0.0
    r_mid = np.sqrt(np.mean(radius[middle] ** 2)) if middle.any() else 0.0
    out = np.concatenate(
        [
            [np.log(height), float(hag.min()) / height],
            share,
            rms / height,
            np.log1p(rms),
            [
                np.log(major),
                minor / major,
                (ev[0] - ev[1]) / ev[0],
                (ev[1] - ev[2]) / ev[0],
                ev[2] / ev[0],
                abs(vec[2, 0]),
                len(slices) / np.ceil(height),
                gaps.max() / height,
                len(vox) / len(columns) / (height / VOXEL_M),
                np.log(len(columns)),
                len(columns) * VOXEL_M * VOXEL_M / area,
                np.log(area),
                np.log1p(r_top) - np.log1p(r_mid),
            ],
        ]
    )
    return out


def object_points(footprint: shapely.Geometry, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points within :data:`OBJECT_BUFFER_M` of a footprint: the object the
    shape check describes."""
    region = shapely.buffer(footprint, OBJECT_BUFFER_M, quad_segs=4)
    xmin, ymin, xmax, ymax = region.bounds
    near = np.flatnonzero((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax))
    return near[shapely.contains_xy(region, x[near], y[near])]


def peak_objects(
    centers: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    hag: np.ndarray,
    *,
    exclude: np.ndarray | None = None,
    radius: float = PEAK_OBJECT_RADIUS,
    tree: Any = None,
) -> list[np.ndarray | None]:
    """The objects at height peaks, as the shape gate and the verifier's training cut them.

    The object at a peak is the convex hull of the points at least
    :data:`PEAK_OBJECT_MIN_HAG` m high within ``radius`` of it (``exclude``: overhead wires
    left out), and then every point within :data:`OBJECT_BUFFER_M` of that hull
    (:func:`object_points`), as the towers step describes a tower.

    Parameters
    ----------
    centers
        ``(P, 2)`` peak locations.
    x, y, hag
        The points around them (model-input points of a tile).
    exclude
        Bool mask of points that are no part of an object (overhead wires).
    radius
        Plan radius (m) of the object around its peak.
    tree
        A ``scipy.spatial.cKDTree`` of ``(x, y)`` (built here if not given).

    Returns
    -------
    list
        Per peak, the indices of its object's points, or ``None`` for a peak with fewer
        than 5 points around it.
    """
    from scipy.spatial import cKDTree

    x, y, hag = (np.asarray(a, np.float64) for a in (x, y, hag))
    centers = np.asarray(centers, np.float64).reshape(-1, 2)
    out: list[np.ndarray | None] = [None] * len(centers)
    keep = hag >= PEAK_OBJECT_MIN_HAG
    if exclude is not None:
        keep &= ~np.asarray(exclude, dtype=bool)
    if len(centers) == 0 or not keep.any():
        return out
    # the object lies within radius + OBJECT_BUFFER_M of its peak: one tree of the tile's points
    tree = cKDTree(np.c_[x, y]) if tree is None else tree
    for i, local in enumerate(tree.query_ball_point(centers, radius + OBJECT_BUFFER_M)):
        local = np.sort(np.asarray(local, np.int64))  # in the points' order, whatever the tree
        d = np.hypot(x[local] - centers[i, 0], y[local] - centers[i, 1])
        near = local[keep[local] & (d <= radius)]
        if len(near) < 5:
            continue
        hull = plan_hull(np.c_[x[near], y[near]])
        out[i] = local[object_points(hull, x[local], y[local])]
    return out


def core_object(top: Sequence[float], x: np.ndarray, y: np.ndarray, hag: np.ndarray) -> np.ndarray | None:
    """The core of the object topped at ``top``: :func:`peak_objects` within
    :data:`PEAK_CORE_RADIUS` of it, from the points near it only (no tree of all of them).

    Returns
    -------
    numpy.ndarray or None
        Indices of the core's points, or ``None`` with fewer than 5 points around the top.
    """
    reach = PEAK_CORE_RADIUS + OBJECT_BUFFER_M
    tx, ty = (float(v) for v in top)
    near = np.flatnonzero((np.abs(np.asarray(x) - tx) <= reach) & (np.abs(np.asarray(y) - ty) <= reach))
    obj = peak_objects(np.array([[tx, ty]]), x[near], y[near], hag[near], radius=PEAK_CORE_RADIUS)[0]
    return None if obj is None else near[obj]


def peak_scores(
    verifier: ShapeVerifier, objects: Sequence[np.ndarray | None], x: np.ndarray, y: np.ndarray, hag: np.ndarray
) -> np.ndarray:
    """Shape scores of the objects at height peaks (the shape gate of the inference).

    Parameters
    ----------
    verifier
        The shape verifier.
    objects
        Per peak, the indices of its object's points or ``None`` (:func:`peak_objects`).
    x, y, hag
        The points the indices refer to.

    Returns
    -------
    numpy.ndarray
        ``(P,)`` scores in [0, 1]; 0 for a peak without an object.
    """
    x, y, hag = (np.asarray(a, np.float64) for a in (x, y, hag))
    out = np.zeros(len(objects))
    rows = [i for i, obj in enumerate(objects) if obj is not None]
    if rows:
        desc = np.stack([shape_descriptor(x[objects[i]], y[objects[i]], hag[objects[i]]) for i in rows])
        out[rows] = verifier.score_descriptors(desc)
    return out


class ShapeVerifier:
    """The shape score of objects: a small MLP over the standardised :func:`shape_descriptor`.

    Parameters
    ----------
    weights
        ``{"mean", "std", "layers": [[W, b], ...]}`` as written by
        :func:`towerpipe.training.verifier.train_verifier` (ReLU between layers, sigmoid out).
    card
        The verifier's card (name, version, training data, figures).
    """

    def __init__(self, weights: dict[str, Any], card: dict[str, Any] | None = None):
        self.mean = np.asarray(weights["mean"], np.float64)
        self.std = np.asarray(weights["std"], np.float64)
        self.layers = [(np.asarray(w, np.float64), np.asarray(b, np.float64)) for w, b in weights["layers"]]
        self.card = dict(card or {})
        if len(self.mean) != len(DESCRIPTOR_NAMES):
            raise ValueError(
                f"shape verifier expects {len(self.mean)} descriptor entries, this towerpipe makes "
                f"{len(DESCRIPTOR_NAMES)}: retrain it (`towerpipe train-verifier`)"
            )

    @property
    def name(self) -> str:
        return str(self.card.get("name", ""))

    def score_descriptors(self, desc: np.ndarray) -> np.ndarray:
        """Shape scores in [0, 1] of ``(n, d)`` descriptors."""
        h = (np.atleast_2d(np.asarray(desc, np.float64)) - self.mean) / self.std
        for i, (w, b) in enumerate(self.layers):
            h = h @ w.T + b
            if i < len(self.layers) - 1:
                h = np.maximum(h, 0.0)
        return 1.0 / (1.0 + np.exp(-np.clip(h[:, 0], -50, 50)))

    def score(self, x: np.ndarray, y: np.ndarray, hag: np.ndarray) -> float:
        """Shape score of one object's points."""
        return float(self.score_descriptors(shape_descriptor(x, y, hag)[None])[0])


def resolve_verifier(spec: str) -> Path | None:
    """The verifier directory of ``towers.verifier``: ``shipped`` (the released one, in the
    models directory), ``none`` (no shape check) or a directory."""
    from towerpipe.model.cards import models_dir

    if spec == "none":
        return None
    if spec == "shipped":
        return models_dir() / f"towerpipe-verifier-v{VERIFIER_RELEASE}"
    return Path(spec)


@lru_cache(maxsize=8)
def _load(path: str) -> ShapeVerifier:
    from towerpipe.errors import ModelError

    f = Path(path, VERIFIER_FILE)
    if not f.is_file():
        raise ModelError(
            f"{f}: no shape verifier there; train one (`towerpipe train-verifier`) or set "
            "`towers.verifier: none` to report towers without the shape check"
        )
    data = json.loads(f.read_text())
    return ShapeVerifier(data["weights"], data.get("card"))


def load_verifier(spec: str | os.PathLike[str]) -> ShapeVerifier | None:
    """The verifier of ``towers.verifier`` (see :func:`resolve_verifier`), loaded once per process."""
    path = resolve_verifier(str(spec))
    return None if path is None else _load(str(path.resolve()))
