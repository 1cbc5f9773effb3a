"""Real tower shapes (towerpipe.synth.real): the ground layer some sources label as tower, left out of zones."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
import shapely

from conftest import TOWERS, real_tile_zone
from towerpipe.synth import generate_zone
from towerpipe.synth.delivery import SOURCE_GROUND
from towerpipe.synth.real import (
    GROUND_LAYER,
    SLOPED_LAYER,
    RealTowerLibrary,
    ground_layer,
    ground_layer_top,
    load_real_towers,
)


def _legs(rng: np.random.Generator, n: int = 400, half: float = 2.0, height: float = 20.0) -> np.ndarray:
    """Four legs of a lattice leaning in from a 4 m square base to a 1 m top."""
    z = rng.uniform(0, height, n)
    k = rng.integers(4, size=n)
    corner = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], float)[k]
    w = half + (0.5 - half) * z / height
    return np.c_[corner * w[:, None] + rng.normal(0, 0.05, (n, 2)), z]


def test_a_filled_layer_at_the_base_is_ground_and_legs_are_not():
    rng = np.random.default_rng(0)
    legs = _legs(rng)
    assert ground_layer_top(legs) == 0.0
    # the ground in the footprint, labelled with the tower: a 4 x 4 m surface 0-0.8 m up
    slab = np.c_[rng.uniform(-2, 2, (600, 2)), rng.uniform(0, 0.8, 600)]
    assert ground_layer_top(np.r_[legs, slab]) == GROUND_LAYER["DEPTH"]
    # on sloping ground the layer reaches higher: slices that still fill half its plan join it
    sloped = np.r_[legs, slab, np.c_[rng.uniform(-2, 2, (600, 2)), rng.uniform(1.0, 1.25, 600)]]
    assert ground_layer_top(sloped) == GROUND_LAYER["DEPTH"] + 0.25
    # a pole's foot or a layer smaller than GROUND_LAYER["AREA"] is no ground
    pole = np.c_[rng.normal(0, 0.1, (300, 2)), rng.uniform(0, 15, 300)]
    assert ground_layer_top(pole) == 0.0
    small = np.c_[rng.uniform(-0.6, 0.6, (300, 2)), rng.uniform(0, 0.8, 300)]
    assert ground_layer_top(np.r_[pole, small]) == 0.0
    assert ground_layer_top(np.zeros((2, 3))) == 0.0


def test_a_sloping_filled_layer_wider_than_the_tower_is_ground():
    rng = np.random.default_rng(1)
    # a thin mast over ground sloping 15 degrees, the source's box cutting a 4 x 4 m piece of it,
    # with shrubs on it and a few points of the mast's foot lower than all of it
    mast = np.c_[rng.normal(0, 0.15, (300, 2)), rng.uniform(2.2, 18, 300)]
    foot = np.c_[rng.normal(0, 0.1, (10, 2)), rng.uniform(0, 0.3, 10)]
    xy = rng.uniform(-2, 2, (800, 2))
    ground = np.c_[xy, 1.7 + np.tan(np.radians(15)) * xy[:, 0] + rng.normal(0, 0.1, 800)]
    shrubs = np.c_[xy[:200], ground[:200, 2] + rng.uniform(0.45, 0.7, 200)]
    xyz = np.r_[mast, foot, ground, shrubs]
    assert ground_layer_top(xyz) == 0.0  # the lowest metre holds too little of it to be level ground
    layer = ground_layer(xyz)
    assert layer[300:].all() and not layer[:300][mast[:, 2] > 3.0].any()
    # a lattice's base bracing is as wide as its body: no ground, however filled
    legs = _legs(rng)
    bracing = np.c_[rng.uniform(-1.9, 1.9, (400, 2)), rng.uniform(1.0, 1.3, 400)]
    assert not ground_layer(np.r_[legs, bracing]).any()
    assert not ground_layer(legs).any() and not ground_layer(np.zeros((2, 3))).any()


@pytest.mark.shared
def test_the_real_sets_whose_ground_is_labelled_tower():
    """Some TS40K sets hold the ground under the tower (a large share of their points); no UAV
    lattice does."""
    tops = {name: (ground_layer_top(xyz), xyz) for name, xyz in load_real_towers(TOWERS)}
    ts40k = {n: v for n, v in tops.items() if n.startswith("ts40k:") and v[0] > 0}
    assert len(ts40k) >= 3
    for top, xyz in ts40k.values():
        assert (xyz[:, 2] < top).mean() > 0.2
    assert not any(top for n, (top, _) in tops.items() if n.startswith("uav:"))
    layers = {name: ground_layer(xyz) for name, (_, xyz) in tops.items()}
    # two more TS40K sets hold ground on a slope under a mast (sample_575, sample_588)
    sloped = [n for n, m in layers.items() if m.any() and tops[n][0] == 0 and n.startswith("ts40k:")]
    assert len(sloped) >= 2 and all(layers[n].mean() > 0.5 for n in sloped)
    assert not any(m.any() for n, m in layers.items() if n.startswith("uav:"))


def _points(truth) -> dict[str, np.ndarray]:
    lases = [laspy.read(b["path"]) for b in truth.blocks]
    return {
        k: np.concatenate([np.asarray(getattr(las, k)) for las in lases])
        for k in ("x", "y", "z", "classification", "TowerId")
    }


def _assert_no_source_ground(truth, lib: RealTowerLibrary) -> int:
    """Every tower point is class 15 with its id, each truth row counts exactly those, no point of a
    source's ground is written, and a tower drawn from a set with a ground layer starts above it.
    Returns how many such towers the zone has."""
    p = _points(truth)
    tower = p["classification"] == 15
    assert (p["TowerId"][tower] > 0).all() and not p["TowerId"][~tower].any()
    assert not (p["classification"] == SOURCE_GROUND).any()
    layered = 0
    for _, r in truth.towers.iterrows():
        own = p["TowerId"] == r["tower_id"]
        assert own.sum() == r["n_points"]
        name = r["design"].removeprefix("real:")
        if not lib.ground_layers[name].any() or not own.any():
            continue
        layered += 1
        assert p["z"][own].min() > r["base_z"] + 0.2
    return layered


@pytest.mark.shared
def test_a_real_towers_source_ground_is_left_out_on_a_real_tile(tmp_path):
    lib = RealTowerLibrary(TOWERS, ["ts40k"])
    t = generate_zone(tmp_path, **real_tile_zone(5, "ts40k", (10, 15)))
    assert _assert_no_source_ground(t, lib) >= 1


@pytest.mark.shared
def test_a_real_towers_source_ground_is_left_out_in_a_generated_zone(tmp_path):
    lib = RealTowerLibrary(TOWERS, ["ts40k"])
    t = generate_zone(
        tmp_path,
        seed=3,
        blocks=2,
        size=200.0,
        density=12.0,
        preset="test",
        tower_source="real",
        real_towers=TOWERS,
        tower_families=["ts40k"],
    )
    layered = _assert_no_source_ground(t, lib)
    assert layered >= 1
    # the tile's own points under such a tower: no class-1 layer over its ground any more
    p = _points(t)
    for _, r in t.towers.iterrows():
        if lib.ground_layers[r["design"].removeprefix("real:")].any():
            fp = shapely.Polygon(r["geometry"].exterior).buffer(2.0)
            low = (p["classification"] == 1) & (p["z"] < r["base_z"] + SLOPED_LAYER["LOW"])
            assert not shapely.contains_xy(fp, p["x"][low], p["y"][low]).any()
