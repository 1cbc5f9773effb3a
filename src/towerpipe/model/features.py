"""The paper's per-point input vector, computed identically for training and inference.

Carós et al. (2022, sec. 5.2) represent each point by a 7-vector: x, y, z normalised
to the unit sphere, intensity, green, blue and NDVI = (NIR - red) / (NIR + red).
Four feature sets exist, from the richest to the barest; each needs the sensor attributes
(:mod:`towerpipe.preprocess.attributes`) of :data:`REQUIRED_ATTRIBUTES` to be valid on the data:

``full``
    the paper's vector ``x y z intensity green blue ndvi`` (intensity, RGB and NIR);
``rgb``
    for colourised data without NIR: ``x y z red green blue`` (RGB);
``geometry``
    for data without colour: ``x y z intensity return_ratio n_returns`` (intensity, returns);
``shape``
    coordinates and height above ground only: ``x y z`` (nothing).

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

#: Feature sets: the columns of the model input, in order.
FEATURE_SETS: dict[str, list[str]] = {
    "full": ["x", "y", "z", "intensity", "green", "blue", "ndvi"],
    "rgb": ["x", "y", "z", "red", "green", "blue"],
    "geometry": ["x", "y", "z", "intensity", "return_ratio", "n_returns"],
    "shape": ["x", "y", "z"],
}

#: Every feature column known, in a fixed order (the union of the feature sets).
ALL_FEATURES: list[str] = ["x", "y", "z", "intensity", "green", "blue", "ndvi", "return_ratio", "n_returns", "red"]

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
    }


def compute_columns(
    arrays: Mapping[str, np.ndarray],
    idx: np.ndarray,
    center_xy: tuple[float, float],
    names: list[str],
    meta: Mapping[str, Any],
) -> np.ndarray:
    """Feature columns ``names`` (any of :data:`ALL_FEATURES`) for points ``idx``.

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

    Returns
    -------
    numpy.ndarray
        ``(len(idx), len(names))`` float32.
    """
    idx = np.asarray(idx)
    out = np.empty((idx.size, len(names)), dtype=np.float32)
    cache: dict[str, np.ndarray] = {}

    def col(name: str) -> np.ndarray:
        if name not in cache:
            cache[name] = np.asarray(arrays[name])[idx]
        return cache[name]

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
) -> np.ndarray:
    """Model input for the points ``idx`` of one window.

    Parameters
    ----------
    arrays
        Tile arrays (see :mod:`towerpipe.io.tiles`).
    idx
        Indices of the window's (sampled or all) points.
    center_xy
        Window centre in absolute coordinates.
    feature_set
        ``"full"`` or ``"geometry"``.
    meta
        Tile metadata, ideally from :func:`tile_feature_meta` (holds ``intensity_scale``).

    Returns
    -------
    numpy.ndarray
        ``(len(idx), C)`` float32 with the columns of ``FEATURE_SETS[feature_set]``.
    """
    names = _check_set(feature_set)
    check_meta(feature_set, meta)
    return compute_columns(arrays, idx, center_xy, names, meta)
