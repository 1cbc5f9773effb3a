"""The attributes of the points set into a real tile, and the degraded deliveries of a zone.

Inserted points are coloured as a colourised flight colours them: a share of a tower's
points (:attr:`~towerpipe.synth.params.SceneParams.tower_own_color`) takes the tower's own
colour, the rest the colour of the background point below (the orthophoto pixel: ground,
grass, shadow); intensity is the material's reflectance relative to the tile's ground
intensity, times a factor drawn per tower; scan angle, GPS time and source id are those
of the nearest background point. A tile without NIR gets a synthetic NIR (high on
vegetation, about red elsewhere); one without colour an orthophoto colour from its classes.

``variant`` then degrades the whole zone as public data sets often are:
``no_intensity`` (intensity, return numbers, scan angle and GPS time all 0),
``no_nir`` (NIR all 0), ``no_colour`` (point format 6: no RGB, no NIR) or ``no_wire_class``
(the conductors class 1, as ``wire_class: false`` delivers them).
"""

from __future__ import annotations

import laspy
import numpy as np
from scipy.spatial import cKDTree

from towerpipe import classes
from towerpipe.synth import color as col

__all__ = ["SOURCE_GROUND", "VARIANTS", "degrade", "drop_source_ground", "tile_colour", "with_attributes"]

#: The class a real tower source's ground points (:func:`towerpipe.synth.real.ground_layer`) carry
#: while a zone draws their attributes; :func:`drop_source_ground` then leaves them out. The tile or
#: the scene has its own ground there, and the source's, set in over it, would hover over it (a
#: sloping piece 1-3 m up). Drawn and then dropped, they leave every other point as it was.
SOURCE_GROUND = 255

#: Ways a zone's attributes are degraded (see the module docstring).
VARIANTS = ("intact", "no_intensity", "no_nir", "no_colour", "no_wire_class")
_GROUND_BASE = 0.35  # reflectance of ground in towerpipe.synth.color (intensity reference)


def tile_colour(las: laspy.LasData, cls: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``(n, 4)`` RGB + NIR in [0, 1] of a background tile (synthetic where it has none)."""
    n = len(cls)
    dims = set(las.point_format.dimension_names)
    if "red" in dims and np.asarray(las.red).max() > 0:
        rgb = np.c_[[np.asarray(las[c]).astype(np.float32) / 65535 for c in ("red", "green", "blue")]].T
        if rgb.max() <= 255 / 65535:  # 8-bit colour stored raw
            rgb *= 257
    else:  # an orthophoto colour from the classes
        mat = np.select([np.isin(cls, [3, 4, 5]), cls == 6], [col.TREE, col.ROOF], col.GROUND)
        rgb = col.colors(mat, np.arange(n) // 50, np.full(n, 0.5), rng)[:, :3]
    if "nir" in dims and np.asarray(las.nir).max() > 0:
        nir = np.asarray(las.nir).astype(np.float32) / 65535
    else:
        veg = np.isin(cls, [3, 4, 5])
        nir = np.where(veg, np.clip(0.35 + 1.6 * rgb[:, 1], 0, 1), np.clip(rgb[:, 0] * 0.95, 0, 1))
    return np.c_[rgb, nir].astype(np.float32)


def with_attributes(las: laspy.LasData, xyz: np.ndarray, cls: np.ndarray, parts, rng: np.random.Generator) -> dict:
    """The tile's points plus the inserted ``parts`` (points, class, tower id, material, own colour share,
    intensity factor; class and tower id per part or per point), with their attributes."""
    n0 = len(xyz)
    dims = set(las.point_format.dimension_names)

    def get(name, default):
        return np.asarray(las[name]) if name in dims else default

    colour = tile_colour(las, cls, rng)
    inten = get("intensity", np.zeros(n0, np.uint16)).astype(np.float64)
    gint = inten[cls == 2]
    scale = float(np.median(gint)) if len(gint) and np.median(gint) > 0 else 10000.0
    sa = get("scan_angle", np.zeros(n0)) * (0.006 if las.point_format.id >= 6 else 1.0)
    gps = get("gps_time", np.zeros(n0))
    psid = get("point_source_id", np.zeros(n0))
    tree = cKDTree(xyz[:, :2])
    add = {k: [] for k in ("xyz", "cls", "tid", "rgbn", "int", "rn", "nr", "sa", "gps", "psid")}
    for pts, klass, tid, material, own_share, factor in parts:
        m = len(pts)
        if not m:
            continue
        _, near = tree.query(pts[:, :2])
        own = rng.random(m) < own_share
        c = colour[near].copy()
        c[own] = col.colors(
            np.full(int(own.sum()), material), np.zeros(int(own.sum()), int), np.zeros(int(own.sum())), rng
        )
        nr = (1 + (rng.random(m) < 0.6)).astype(np.uint8)
        rn = np.where((nr == 2) & (rng.random(m) < 0.25), 2, 1).astype(np.uint8)
        rel = col.intensity(np.full(m, material), rn, nr, rng).astype(np.float64) / (40000.0 * _GROUND_BASE)
        add["xyz"].append(pts)
        add["cls"].append(np.full(m, klass, np.uint8))
        add["tid"].append(np.full(m, tid, np.uint32))
        add["rgbn"].append(c)
        add["int"].append(np.clip(rel * scale * factor, 0, 65535))
        add["rn"].append(rn)
        add["nr"].append(nr)
        add["sa"].append(sa[near])
        add["gps"].append(gps[near])
        add["psid"].append(psid[near])
    cat = {k: (np.concatenate(v) if v else None) for k, v in add.items()}
    m = 0 if cat["xyz"] is None else len(cat["xyz"])

    def join(a, b, dtype):
        return np.r_[a, b if b is not None else np.zeros(0)].astype(dtype)

    rgbn = np.r_[colour, cat["rgbn"] if m else np.zeros((0, 4))]
    return {
        "x": join(xyz[:, 0], None if not m else cat["xyz"][:, 0], np.float64),
        "y": join(xyz[:, 1], None if not m else cat["xyz"][:, 1], np.float64),
        "z": join(xyz[:, 2], None if not m else cat["xyz"][:, 2], np.float64),
        "classification": join(cls, cat["cls"], np.uint8),
        "tower_id": join(np.zeros(n0), cat["tid"], np.uint32),
        "return_number": join(get("return_number", np.ones(n0)), cat["rn"], np.uint8),
        "number_of_returns": join(get("number_of_returns", np.ones(n0)), cat["nr"], np.uint8),
        "intensity": join(inten, cat["int"], np.uint16),
        "red": col.to16(rgbn[:, 0]),
        "green": col.to16(rgbn[:, 1]),
        "blue": col.to16(rgbn[:, 2]),
        "nir": col.to16(rgbn[:, 3]),
        "point_source_id": join(psid, cat["psid"], np.uint16),
        "scan_angle": join(sa, cat["sa"], np.float32),
        "gps_time": join(gps, cat["gps"], np.float64),
    }


def drop_source_ground(pts: dict) -> dict:
    """The points of a zone without those of class :data:`SOURCE_GROUND` (every array alike)."""
    keep = np.asarray(pts["classification"]) != SOURCE_GROUND
    return pts if keep.all() else {k: np.asarray(v)[keep] for k, v in pts.items()}


def degrade(pts: dict, variant: str) -> dict:
    """The attributes a degraded export keeps (see :data:`VARIANTS`)."""
    if variant == "no_intensity":
        for k in ("intensity", "return_number", "number_of_returns", "scan_angle", "gps_time"):
            pts[k] = np.zeros_like(pts[k])
    elif variant == "no_nir":
        pts["nir"] = np.zeros_like(pts["nir"])
    elif variant == "no_wire_class":
        pts["classification"][np.isin(pts["classification"], classes.WIRE)] = classes.OTHER
    return pts
