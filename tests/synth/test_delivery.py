"""Attributes of points set into a real tile, and degraded deliveries (towerpipe.synth.delivery)."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from towerpipe import classes
from towerpipe.synth import color as col
from towerpipe.synth.delivery import (
    SOURCE_GROUND,
    VARIANTS,
    degrade,
    drop_source_ground,
    tile_colour,
    with_attributes,
)


def _tile(n: int = 200, seed: int = 0) -> tuple[laspy.LasData, np.ndarray, np.ndarray]:
    """A small tile of point format 8: ground and trees, intensity, RGB and NIR."""
    rng = np.random.default_rng(seed)
    las = laspy.LasData(laspy.LasHeader(point_format=8, version="1.4"))
    xyz = np.c_[rng.uniform(0, 50, (n, 2)), rng.uniform(100, 101, n)]
    las.x, las.y, las.z = xyz.T
    cls = np.where(np.arange(n) % 4 == 0, 5, 2).astype(np.uint8)
    las.classification = cls
    las.intensity = rng.integers(1000, 3000, n).astype(np.uint16)
    for c in ("red", "green", "blue", "nir"):
        las[c] = rng.integers(1, 65535, n).astype(np.uint16)
    return las, xyz, cls


def test_inserted_points_take_their_class_and_tower_id_per_point():
    """A tower part may label some of its points otherwise (a real source's ground layer): class
    and tower id are taken point by point, the tile's own points are kept first and unchanged."""
    las, xyz, cls = _tile()
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(20, 30, (30, 2)), rng.uniform(100, 120, 30)]
    ground = np.arange(30) < 10
    parts = [(pts, np.where(ground, classes.OTHER, classes.TOWER), np.where(ground, 0, 7), col.STEEL, 0.5, 1.0)]
    out = with_attributes(las, xyz, cls, parts, rng)
    n0 = len(xyz)
    assert len(out["x"]) == n0 + 30
    np.testing.assert_array_equal(out["classification"][:n0], cls)
    np.testing.assert_array_equal(out["classification"][n0:], np.where(ground, classes.OTHER, classes.TOWER))
    np.testing.assert_array_equal(out["tower_id"][n0:], np.where(ground, 0, 7))
    assert not out["tower_id"][:n0].any()
    # a whole part at one class still works, as for conductors and cranes
    out = with_attributes(las, xyz, cls, [(pts, classes.WIRE_CONDUCTOR, 0, col.WIRE, 0.3, 1.0)], rng)
    assert (out["classification"][n0:] == classes.WIRE_CONDUCTOR).all()


def test_a_sources_ground_takes_its_draws_and_is_then_left_out():
    """Points of class SOURCE_GROUND draw their attributes like any other and are then dropped: every
    other point is what it would be with them set in."""
    las, xyz, cls = _tile()
    pts = np.c_[np.random.default_rng(2).uniform(20, 30, (30, 2)), np.linspace(100, 120, 30)]
    ground = np.arange(30) < 10
    kept = with_attributes(
        las,
        xyz,
        cls,
        [(pts, np.where(ground, classes.OTHER, classes.TOWER), 7, col.STEEL, 0.5, 1.0)],
        np.random.default_rng(3),
    )
    out = drop_source_ground(
        with_attributes(
            las,
            xyz,
            cls,
            [(pts, np.where(ground, SOURCE_GROUND, classes.TOWER), 7, col.STEEL, 0.5, 1.0)],
            np.random.default_rng(3),
        )
    )
    keep = np.r_[np.ones(len(xyz), bool), ~ground]
    assert set(out) == set(kept) and len(out["x"]) == len(xyz) + 20
    for k in out:
        np.testing.assert_array_equal(out[k], np.asarray(kept[k])[keep])
    assert drop_source_ground(kept) is kept  # nothing to drop: the same points


def test_a_tile_without_nir_gets_one_and_its_own_colour_is_kept():
    las, _, cls = _tile()
    rgbn = tile_colour(las, cls, np.random.default_rng(0))
    np.testing.assert_allclose(rgbn[:, 0], np.asarray(las.red) / 65535, atol=1e-6)
    las.nir = np.zeros(len(cls), np.uint16)
    rgbn = tile_colour(las, cls, np.random.default_rng(0))
    veg = cls == 5
    assert rgbn[veg, 3].mean() > 0.3 and (rgbn[:, 3] > 0).all()


@pytest.mark.parametrize("variant", VARIANTS)
def test_each_variant_degrades_only_what_it_names(variant):
    las, xyz, cls = _tile()
    cls = cls.copy()
    cls[:5] = classes.WIRE_CONDUCTOR
    pts = with_attributes(las, xyz, cls, [], np.random.default_rng(0))
    before = {k: v.copy() for k, v in pts.items()}
    after = degrade({k: v.copy() for k, v in pts.items()}, variant)
    gone = {
        "no_intensity": {"intensity", "return_number", "number_of_returns", "scan_angle", "gps_time"},
        "no_nir": {"nir"},
        "no_wire_class": {"classification"},
    }.get(variant, set())
    for k in before:
        if k in gone and k != "classification":
            assert not after[k].any(), k
        elif k != "classification":
            np.testing.assert_array_equal(after[k], before[k])
    expected = np.where(np.isin(cls, classes.WIRE), classes.OTHER, cls) if "classification" in gone else cls
    np.testing.assert_array_equal(after["classification"], expected)
