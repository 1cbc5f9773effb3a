"""Training-time augmentation of sampled windows: geometry, and attribute dropout and corruption.

Geometry (:func:`augment_geometry`): a rotation about the vertical axis, an isotropic
scale and a coordinate jitter of the ``x, y, z`` columns (always the first three).

Attributes (:func:`corrupt_attributes`): a model that may read intensity, colour, NIR or
returns must not collapse when the data it meets carries one of them badly. Real exports
zero a column, leave it constant, store colour as 8 bits in 16-bit fields, use another
intensity scale, or colour a tower with the orthophoto pixel under it rather than its own
steel. So, per window and per attribute group (:data:`towerpipe.model.features.COLUMN_ATTRIBUTES`:
intensity, rgb, nir, returns), with probability ``p`` one of :data:`OPERATIONS` is applied
to the group's columns:

``zero``      the export wrote 0;
``constant``  one value for every point (a re-export, a single-return sensor);
``rescale``   another sensor scale (x 0.3 to 3, clipped to the column's range);
``bits8``     8-bit values read as 16-bit (colour / 257, intensity / 256);
``permute``   the values shuffled among the window's points (no link to the points);
``swap``      the tower points take the values of random other points of the window (a
              tower coloured and reflecting as its surroundings).

Shape, the one thing every real tower keeps, is then what the networks learn to rely on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from towerpipe.model.features import COLUMN_ATTRIBUTES, INTENSITY_CLIP, NORM_RADIUS

#: The corruptions of an attribute group (see the module docstring).
OPERATIONS: tuple[str, ...] = ("zero", "constant", "rescale", "bits8", "permute", "swap")
#: Range of each corruptible column after normalisation (:mod:`towerpipe.model.features`).
_RANGE = {
    "intensity": (0.0, INTENSITY_CLIP),
    "red": (0.0, 1.0),
    "green": (0.0, 1.0),
    "blue": (0.0, 1.0),
    "ndvi": (-1.0, 1.0),
    "return_ratio": (0.0, 1.0),
    "n_returns": (0.0, 1.0),
}


def augment_geometry(x: np.ndarray, cfg: Mapping[str, Any], rng: np.random.Generator) -> np.ndarray:
    """Rotation about z, isotropic scale and jitter of the x, y, z columns of ``(B, n, C)``, in place.

    ``cfg``: ``rotate`` (bool), ``scale`` (relative range, e.g. 0.1 for x 0.9-1.1; 0 off) and
    ``jitter_m`` (standard deviation in metres; 0 off).
    """
    if cfg.get("rotate"):
        a = rng.uniform(0, 2 * np.pi, size=len(x)).astype(np.float32)
        c, s = np.cos(a)[:, None], np.sin(a)[:, None]
        xx, yy = x[..., 0].copy(), x[..., 1].copy()
        x[..., 0] = c * xx - s * yy
        x[..., 1] = s * xx + c * yy
    if cfg.get("scale"):
        f = rng.uniform(1 - float(cfg["scale"]), 1 + float(cfg["scale"]), size=len(x)).astype(np.float32)
        x[..., :3] *= f[:, None, None]
    if cfg.get("jitter_m"):
        x[..., :3] += rng.normal(0, float(cfg["jitter_m"]) / NORM_RADIUS, size=x[..., :3].shape).astype(np.float32)
    return x


def attribute_groups(names: Sequence[str]) -> dict[str, list[int]]:
    """Column indices of each attribute group present in a feature list."""
    out: dict[str, list[int]] = {}
    for j, n in enumerate(names):
        if n in COLUMN_ATTRIBUTES:
            out.setdefault(COLUMN_ATTRIBUTES[n], []).append(j)
    return out


def corrupt_attributes(
    x: np.ndarray,
    names: Sequence[str],
    labels: np.ndarray | None,
    p: float,
    rng: np.random.Generator,
    operations: Sequence[str] = OPERATIONS,
) -> np.ndarray:
    """Apply attribute corruptions to ``(B, n, C)`` windows in place (see the module docstring).

    Parameters
    ----------
    x
        Sampled windows; column ``j`` holds feature ``names[j]``.
    names
        The feature names of the columns.
    labels
        ``(B, n)`` point labels (1 = tower), for ``swap``; ``None``: ``swap`` acts as ``permute``.
    p
        Probability, per window and group, of a corruption.
    rng
        Random generator.
    operations
        The operations drawn from (uniformly).

    Returns
    -------
    numpy.ndarray
        ``x``.
    """
    if p <= 0:
        return x
    groups = attribute_groups(names)
    b, n, _ = x.shape
    for cols in groups.values():
        lo = np.array([_RANGE[names[j]][0] for j in cols], np.float32)
        hi = np.array([_RANGE[names[j]][1] for j in cols], np.float32)
        for i in np.flatnonzero(rng.random(b) < p):
            op = operations[int(rng.integers(len(operations)))]
            v = x[i][:, cols]
            if op == "zero":
                v[:] = 0.0
            elif op == "constant":
                v[:] = rng.uniform(lo, np.minimum(hi, 1.0)).astype(np.float32)
            elif op == "rescale":
                v = np.clip(v * np.float32(np.exp(rng.uniform(np.log(0.3), np.log(3.0)))), lo, hi)
            elif op == "bits8":
                v = v / np.float32(257.0 if names[cols[0]] != "intensity" else 256.0)
            elif op == "swap" and labels is not None and labels[i].any() and not labels[i].all():
                tower = np.flatnonzero(labels[i] > 0)
                other = np.flatnonzero(labels[i] == 0)
                v[tower] = v[other[rng.integers(len(other), size=len(tower))]]
            else:  # permute (or swap without both kinds)
                v = v[rng.permutation(n)]
            x[i][:, cols] = v
    return x
