"""The paper's per-point input vector, computed identically for training and inference.

Carós et al. (2022, sec. 5.2) represent each point by a 7-vector: x, y, z normalised
to the unit sphere, intensity, green, blue and NDVI = (NIR - red) / (NIR + red).
Five feature sets exist (the first four from the richest to the barest); each needs the sensor attributes
(:mod:`towerpipe.preprocess.attributes`) of :data:`REQUIRED_ATTRIBUTES` to be valid on the data:

``full``
    the paper's vector ``x y z intensity green blue ndvi`` (intensity, RGB and NIR);
``rgb``
    for colourised data without NIR: ``x y z red green blue`` (RGB);
``geometry``
    for data without colour: ``x y z intensity return_ratio n_returns`` (intensity, returns);
``shape``
    coordinates and height above ground only: ``x y z`` (nothing);
``structure``
    ``shape`` and the local structure of each point: ``x y z linearity planarity scattering
    verticality`` (nothing: read from the coordinates alone, :func:`local_structure`).

Local structure
---------------
A PointNet labels a point from its own coordinates and the window's pooled feature: a
lattice member and the crown beside it, at the same place in the window, read alike. The
``structure`` set adds what a point's neighbourhood looks like: the eigenvalues
``l1 >= l2 >= l3`` of the covariance of its :data:`LOCAL_NEIGHBOURS` nearest points (3-D,
itself included) give ``linearity (l1 - l2) / l1``, ``planarity (l2 - l3) / l1`` and
``scattering l3 / l1`` (a lattice member is a line, a roof a plane, a crown a volume), and
``verticality`` is the vertical component of the principal axis (a leg 1, a crossarm or a
conductor 0). The neighbours are searched among *all* the window's points, in training as
at inference (``sample`` of :func:`compute_columns`): a sample's points keep the structure
they have in the flight. The columns are ratios, so they do not move with the window's
scale, rotation or offset.

Normalisation (fixed, never data-dependent within a window)
-----------------------------------------------------------
A window is the square of side :data:`WINDOW_SIZE` (40 m) around ``center_xy``; its
points have height above ground (HAG) ``h``. With the fixed radius

    ``R = hypot(WINDOW_SIZE / 2 * sqrt(2), HEIGHT_REF)``  (= 57.45 m for 40 m, 50 m)

the coordinates are ``x = (X - cx) / R``, ``y = (Y - cy) / R``, ``z = h / R``. Every point
of a window with HAG up to :data:`HEIGHT_REF` (the tallest tower in the paper, 50 m) lies
in the unit sphere around the ground point below the window centre, and the scaling is
isotropic so tower shapes are not distorted. The paper normalises "into a unit sphere"
without saying how; we deliberately do *not* use the per-window centroid and maximum
radius of the sampled points: those depend on which points the sampler picked (and on
the clutter around the tower), so the same tower would get different coordinates in
training (2048 sampled points) and in inference (all points of the window).

Intensity is sensor dependent: it is divided by a per-tile robust scale, the
95th percentile of the intensity of the tile's model-input points
(:func:`intensity_scale`), and clipped to ``[0, INTENSITY_CLIP]``. Compute the scale
once per tile with :func:`tile_feature_meta` and pass the result as ``meta``;
:func:`window_features` falls back to computing it from ``arrays`` (same value, but
O(tile) work per call). Colour is divided by ``2**meta["color_bits"] - 1``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from towerpipe.errors import ModelError

#: Side of the square window (m).
WINDOW_SIZE = 40.0
#: Reference height (m): a point at this HAG on a window corner lies on the unit sphere.
HEIGHT_REF = 50.0
#: The fixed normalisation radius (m) shared by x, y and z.
NORM_RADIUS = math.hypot(WINDOW_SIZE / 2.0 * math.sqrt(2.0), HEIGHT_REF)
#: Percentile of the tile's model-input intensities used as the intensity scale.
INTENSITY_PERCENTILE = 95.0
#: Normalised intensity is clipped to ``[0, INTENSITY_CLIP]``.
INTENSITY_CLIP = 3.0
#: Number of returns is divided by this and clipped to 1.
MAX_RETURNS = 5.0
#: Neighbours (the point included) whose covariance gives a point's local structure.
LOCAL_NEIGHBOURS = 10
#: The local-structure columns (:func:`local_structure`), in order.
LOCAL_STRUCTURE: list[str] = ["linearity", "planarity", "scattering", "verticality"]

#: Feature sets: the columns of the model input, in order.
FEATURE_SETS: dict[str, list[str]] = {
    "full": ["x", "y", "z", "intensity", "green", "blue", "ndvi"],
    "rgb": ["x", "y", "z", "red", "green", "blue"],
    "geometry": ["x", "y", "z", "intensity", "return_ratio", "n_returns"],
    "shape": ["x", "y", "z"],
    "structure": ["x", "y", "z", *LOCAL_STRUCTURE],
}

#: Every feature column known, in a fixed order (the union of the feature sets).
ALL_FEATURES: list[str] = [
    "x",
    "y",
    "z",
    "intensity",
    "green",
    "blue",
    "ndvi",
    "return_ratio",
    "n_returns",
    "red",
    *LOCAL_STRUCTURE,
]

#: The sensor attributes (:data:`towerpipe.preprocess.attributes.ATTRIBUTES`) each feature column reads.
COLUMN_ATTRIBUTES: dict[str, str] = {
    "intensity": "intensity",
    "red": "rgb",
    "green": "rgb",
    "blue": "rgb",
    "ndvi": "nir",
    "return_ratio": "returns",
    "n_returns": "returns",
}
#: The sensor attributes each feature set needs to be valid.
REQUIRED_ATTRIBUTES: dict[str, list[str]] = {
    name: sorted(
        {COLUMN_ATTRIBUTES[c] for c in cols if c in COLUMN_ATTRIBUTES} | ({"rgb"} if "ndvi" in cols else set())
    )
    for name, cols in FEATURE_SETS.items()
}


def _check_set(feature_set: str) -> list[str]:
    if feature_set not in FEATURE_SETS:
        raise ModelError(f"unknown feature set {feature_set!r}; use one of {sorted(FEATURE_SETS)}")
    return FEATURE_SETS[feature_set]


def required_attributes(feature_set: str) -> list[str]:
    """The sensor attributes a feature set needs to be valid on the data.

    Parameters
    ----------
    feature_set
        A key of :data:`FEATURE_SETS`.

    Returns
    -------
    list of str
        e.g. ``["intensity", "nir", "rgb"]`` for ``full``, ``[]`` for ``shape``.
    """
    _check_set(feature_set)
    return list(REQUIRED_ATTRIBUTES[feature_set])


def intensity_scale(arrays: Mapping[str, np.ndarray]) -> float:
    """The tile's robust intensity scale: 95th percentile over model-input points.

    Parameters
    ----------
    arrays
        Tile arrays with ``intensity`` and (optionally) ``model_input``.

    Returns
    -------
    float
        The percentile, or 1.0 when there are no points or all intensities are 0.
    """
    inten = np.asarray(arrays["intensity"])
    if "model_input" in arrays:
        inten = inten[np.asarray(arrays["model_input"], dtype=bool)]
    if inten.size == 0:
        return 1.0
    p = float(np.percentile(inten.astype(np.float64), INTENSITY_PERCENTILE))
    return p if p > 0 else 1.0


def tile_feature_meta(arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of ``meta`` with ``intensity_scale`` set (compute once per tile).

    Parameters
    ----------
    arrays
        Tile arrays.
    meta
        Tile metadata (``color_bits``, ``has_rgb``, ``has_nir`` are read later).
    """
    out = dict(meta)
    out["intensity_scale"] = intensity_scale(arrays)
    return out


def normalisation_spec() -> dict[str, Any]:
    """The normalisation constants, as recorded in every model card."""
    return {
        "window_size_m": WINDOW_SIZE,
        "height_ref_m": HEIGHT_REF,
        "norm_radius_m": NORM_RADIUS,
        "xy": "(X - window centre) / norm_radius",
        "z": "HAG / norm_radius",
        "intensity": f"intensity / P{INTENSITY_PERCENTILE:g}(tile model-input intensity), clipped to [0, {INTENSITY_CLIP:g}]",
        "colour": "value / (2**color_bits - 1)",
        "ndvi": "(nir - red) / (nir + red), 0 where nir + red = 0",
        "return_ratio": "return_number / number_of_returns",
        "n_returns": f"min(number_of_returns / {MAX_RETURNS:g}, 1)",
        "local_structure": (
            f"eigenvalues l1 >= l2 >= l3 of the covariance of the {LOCAL_NEIGHBOURS} nearest points (3-D, "
            "among all the window's points): (l1 - l2) / l1, (l2 - l3) / l1, l3 / l1, |z of the principal axis|"
        ),
    }


def local_structure(x: np.ndarray, y: np.ndarray, hag: np.ndarray, k: int = LOCAL_NEIGHBOURS) -> np.ndarray:
    """The local structure of each point among the given points (:data:`LOCAL_STRUCTURE`).

    Parameters
    ----------
    x, y
        Plan coordinates (m), any offset (only differences are used; pass them relative to a
        nearby origin, not as absolute float32).
    hag
        Heights above ground (m).
    k
        Neighbours, the point itself included (fewer where there are fewer points).

    Returns
    -------
    numpy.ndarray
        ``(n, 4)`` float32: linearity, planarity, scattering, verticality, each in [0, 1];
        zeros where there are fewer than 3 points.
    """
    from scipy.spatial import cKDTree

    pts = np.c_[np.asarray(x, np.float64), np.asarray(y, np.float64), np.asarray(hag, np.float64)]
    n = len(pts)
    if n < 3:
        return np.zeros((n, len(LOCAL_STRUCTURE)), np.float32)
    pts -= pts.mean(axis=0)
    k = min(int(k), n)
    _, nb = cKDTree(pts).query(pts, k=k)
    q = pts[nb]
    q -= q.mean(axis=1, keepdims=True)
    ev, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q) / k)  # ascending eigenvalues
    l3, l2, l1 = (np.clip(ev[:, j], 1e-12, None) for j in range(3))
    out = np.c_[(l1 - l2) / l1, (l2 - l3) / l1, l3 / l1, np.abs(vec[:, 2, 2])]
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def compute_columns(
    arrays: Mapping[str, np.ndarray],
    idx: np.ndarray,
    center_xy: tuple[float, float],
    names: list[str],
    meta: Mapping[str, Any],
    sample: np.ndarray | None = None,
) -> np.ndarray:
    """Feature columns ``names`` (any of :data:`ALL_FEATURES`) for points ``idx`` (or ``idx[sample]``).

    Parameters
    ----------
    arrays
        Tile arrays (``x, y, hag, intensity`` and whatever ``names`` need).
    idx
        Indices of the window's points into ``arrays``.
    center_xy
        Window centre (absolute coordinates).
    names
        Feature columns to compute.
    meta
        Tile metadata: ``color_bits``, and ``intensity_scale`` (else computed).
    sample
        Positions into ``idx`` of the points to describe (a window's sample; repeats allowed);
        ``None``: every point of ``idx``. The local structure is that among all of ``idx``.

    Returns
    -------
    numpy.ndarray
        ``(len(idx), len(names))`` float32 (``len(sample)`` rows with a sample).
    """
    window = np.asarray(idx)
    idx = window if sample is None else window[np.asarray(sample)]
    out = np.empty((idx.size, len(names)), dtype=np.float32)
    cache: dict[str, np.ndarray] = {}

    def col(name: str) -> np.ndarray:
        if name not in cache:
            cache[name] = np.asarray(arrays[name])[idx]
        return cache[name]

    local: np.ndarray | None = None
    if any(n in LOCAL_STRUCTURE for n in names):
        xw = np.asarray(arrays["x"])[window] - float(center_xy[0])
        yw = np.asarray(arrays["y"])[window] - float(center_xy[1])
        local = local_structure(xw, yw, np.asarray(arrays["hag"])[window])
        if sample is not None:
            local = local[np.asarray(sample)]

    bits = int(meta.get("color_bits", 16) or 16)
    cmax = float(2**bits - 1)
    for j, name in enumerate(names):
        if name == "x":
            v = (col("x") - float(center_xy[0])) / NORM_RADIUS
        elif name == "y":
            v = (col("y") - float(center_xy[1])) / NORM_RADIUS
        elif name == "z":
            v = col("hag").astype(np.float64) / NORM_RADIUS
        elif name == "intensity":
            scale = meta.get("intensity_scale")
            if scale is None:
                scale = intensity_scale(arrays)
            v = np.clip(col("intensity").astype(np.float64) / float(scale), 0.0, INTENSITY_CLIP)
        elif name in ("red", "green", "blue"):
            v = np.clip(col(name).astype(np.float64) / cmax, 0.0, 1.0)
        elif name == "ndvi":
            nir = col("nir").astype(np.float64)
            red = col("red").astype(np.float64)
            s = nir + red
            v = np.divide(nir - red, s, out=np.zeros_like(s), where=s > 0)
        elif name == "return_ratio":
            nr = col("number_of_returns").astype(np.float64)
            v = np.clip(col("return_number").astype(np.float64) / np.maximum(nr, 1.0), 0.0, 1.0)
        elif name == "n_returns":
            v = np.minimum(col("number_of_returns").astype(np.float64) / MAX_RETURNS, 1.0)
        elif local is not None and name in LOCAL_STRUCTURE:
            v = local[:, LOCAL_STRUCTURE.index(name)]
        else:
            raise ModelError(f"unknown feature column {name!r}; known: {ALL_FEATURES}")
        out[:, j] = v
    return out


def valid_attributes(meta: Mapping[str, Any]) -> set[str]:
    """The valid sensor attributes of a tile (its ``valid_attributes``, else the older flags)."""
    if "valid_attributes" in meta:
        return set(meta["valid_attributes"])
    out = {"intensity", "returns"}
    if meta.get("has_rgb", True):
        out.add("rgb")
    if meta.get("has_nir", True):
        out.add("nir")
    return out


def missing_attributes(feature_set: str, meta: Mapping[str, Any]) -> list[str]:
    """The attributes ``feature_set`` needs that the tile ``meta`` does not carry validly."""
    return [a for a in required_attributes(feature_set) if a not in valid_attributes(meta)]


def check_meta(feature_set: str, meta: Mapping[str, Any]) -> None:
    """Raise :class:`ModelError` if the tile lacks valid attributes the feature set needs."""
    missing = missing_attributes(feature_set, meta)
    if missing:
        raise ModelError(
            f"feature set {feature_set!r} needs valid {', '.join(required_attributes(feature_set))} but the "
            f"tile {meta.get('tile', '?')!r} has no valid {', '.join(missing)}; set `inference: {{model: auto}}` "
            f"(or a model the data supports) in the config"
        )


def window_features(
    arrays: Mapping[str, np.ndarray],
    idx: np.ndarray,
    center_xy: tuple[float, float],
    feature_set: str,
    meta: Mapping[str, Any],
    sample: np.ndarray | None = None,
) -> np.ndarray:
    """Model input for the points ``idx`` of one window (or its sample ``idx[sample]``).

    Parameters
    ----------
    arrays
        Tile arrays (see :mod:`towerpipe.io.tiles`).
    idx
        Indices of the window's points (all of them where the feature set reads the local
        structure, which is that among ``idx``).
    center_xy
        Window centre in absolute coordinates.
    feature_set
        A key of :data:`FEATURE_SETS`.
    meta
        Tile metadata, ideally from :func:`tile_feature_meta` (holds ``intensity_scale``).
    sample
        Positions into ``idx`` of the points to describe (the sampled window); ``None``: all.

    Returns
    -------
    numpy.ndarray
        ``(len(idx), C)`` (or ``(len(sample), C)``) float32 with the columns of
        ``FEATURE_SETS[feature_set]``.
    """
    names = _check_set(feature_set)
    check_meta(feature_set, meta)
    return compute_columns(arrays, idx, center_xy, names, meta, sample)
