"""Colour (RGB from a synthetic orthophoto), near-infrared and intensity by material.

A real camera colourises lidar with the surface seen from above: every return of
a pulse gets the colour of the pulse's top surface (a ground return under a crown
gets the crown's colour). NIR makes NDVI = (NIR - red) / (NIR + red) high on
vegetation (0.4-0.8) and low on steel, roofs, roads and bare soil (< 0.25).
"""

from __future__ import annotations

import numpy as np

#: material codes
GROUND, ROAD, ROOF, TREE, STEEL, CONCRETE, WOOD, WIRE = range(8)

# (r, g, b, nir, intensity) in [0, 1] per material (variant 0); variants below
_BASE = np.array(
    [
        [0.42, 0.38, 0.28, 0.48, 0.35],  # ground: soil / dry grass (blended with grass by a field)
        [0.30, 0.30, 0.31, 0.31, 0.18],  # road asphalt
        [0.60, 0.32, 0.24, 0.55, 0.45],  # roof (terracotta; other variants below)
        [0.13, 0.26, 0.11, 0.55, 0.40],  # tree foliage
        [0.55, 0.56, 0.57, 0.50, 0.22],  # galvanised steel
        [0.80, 0.80, 0.78, 0.74, 0.60],  # concrete / white paint
        [0.35, 0.27, 0.19, 0.36, 0.30],  # wood
        [0.40, 0.40, 0.42, 0.36, 0.10],  # wire
    ]
)
_ROOF = np.array(
    [[0.60, 0.32, 0.24, 0.55], [0.52, 0.52, 0.53, 0.48], [0.25, 0.24, 0.26, 0.24], [0.78, 0.77, 0.74, 0.70]]
)
_GRASS = np.array([0.22, 0.34, 0.16, 0.62])


def colors(material: np.ndarray, variant: np.ndarray, greenness: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """RGB + NIR in [0, 1], shape (n, 4).

    Parameters
    ----------
    material
        Material code per point (top surface seen from above).
    variant
        Object index (tree / roof) used to vary colours per object.
    greenness
        0..1 blend between bare soil and grass for ground (other materials ignore it).
    rng
        Random generator (pixel noise).
    """
    material = np.asarray(material, np.int64)
    c = _BASE[:, :4].astype(np.float32)[material]
    g = material == GROUND
    w = np.clip(greenness[g], 0, 1)[:, None]
    c[g] = c[g] * (1 - w) + _GRASS[None, :].astype(np.float32) * w
    r = material == ROOF
    c[r] = _ROOF[np.asarray(variant)[r] % 4]
    t = material == TREE
    v = np.asarray(variant)[t].astype(np.int64)
    h = ((v * 2654435761) % 1000) / 1000.0  # per-tree hue jitter
    c[t] *= (0.8 + 0.4 * h)[:, None]
    c[t, 3] = 0.45 + 0.2 * h
    c *= (1.0 + 0.06 * rng.standard_normal(len(c), dtype=np.float32))[:, None]  # shadow / sun
    c += 0.03 * (rng.random(c.shape, dtype=np.float32) - 0.5)
    return np.clip(c, 0.0, 1.0, out=c)


def intensity(
    material: np.ndarray, return_number: np.ndarray, number_of_returns: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Intensity (uint16): reflectance by material, split between returns of a pulse."""
    base = _BASE[np.asarray(material, np.int64), 4]
    split = np.where(number_of_returns > 1, 0.65 / np.sqrt(return_number), 1.0)
    v = base * split * (1.0 + 0.22 * rng.standard_normal(len(base), dtype=np.float32))
    return np.clip(v * 40000.0, 0, 65535).astype(np.uint16)


def to16(c: np.ndarray) -> np.ndarray:
    """[0, 1] float → 16-bit colour (8-bit value × 257)."""
    return (np.round(np.clip(c, 0, 1) * 255).astype(np.uint16) * np.uint16(257)).astype(np.uint16)
