"""Tests of towerpipe.training.verifier: the shape verifier's examples, training and files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_dataset import make_tiles

from towerpipe.errors import ConfigError
from towerpipe.towers.shape import DESCRIPTOR_NAMES, VERIFIER_FILE, load_verifier
from towerpipe.training.verifier import collect_objects, fit_verifier, occlude, train_verifier

#: the footprint view alone, each object seen once, as delivered
FOOTPRINT_ONLY = {"copies": 1, "peak_view": False, "occlusion": 0.0, "density_range": [1e6, 1e6]}


def test_objects_are_towers_and_tall_others_of_the_core(tmp_path):
    paths = make_tiles(tmp_path, n_blocks=2)
    objs = collect_objects(paths, FOOTPRINT_ONLY)
    assert {o["view"] for o in objs} == {"footprint"}
    towers = [o for o in objs if o["label"] == 1]
    others = [o for o in objs if o["label"] == 0]
    assert len(towers) == 4  # two towers a tile, each seen once
    assert {o["kind"] for o in towers} == {"synthetic"}  # no truth: no real family
    assert others and {o["kind"] for o in others} <= {"tree", "building", "other"}
    assert all(o["descriptor"].shape == (len(DESCRIPTOR_NAMES),) for o in objs)
    assert {o["block"] for o in objs} == {"t/b0", "t/b1"}
    # the same tiles and seed give the same examples, whatever the number of processes
    again = collect_objects(paths, FOOTPRINT_ONLY, threads=2)
    np.testing.assert_array_equal(np.stack([o["descriptor"] for o in again]), np.stack([o["descriptor"] for o in objs]))


def test_the_shape_gates_view_adds_the_object_at_each_towers_peak(tmp_path):
    """Each tower also comes as the gate cuts it at its peak; the footprint view stays as it is."""
    paths = make_tiles(tmp_path, n_blocks=2)
    objs = collect_objects(paths, {"copies": 1, "occlusion": 0.0, "density_range": [1e6, 1e6], "peak_view": True})
    peak = [o for o in objs if o["view"] == "peak"]
    # both towers of the first tile are the highest thing around them: a candidate peak on each
    # (in the second, a crown 8 m from one tower is higher)
    assert sum(o["label"] == 1 and o["block"] == "t/b0" for o in peak) == 2
    footprint = collect_objects(paths, FOOTPRINT_ONLY)
    assert len(objs) == len(footprint) + len(peak)  # the footprint view is unchanged
    assert {o["kind"] for o in peak if o["label"] == 0} <= {"tree", "building", "other"}


def test_occlusion_thins_the_foot_or_hides_a_side():
    rng = np.random.default_rng(0)
    n = 20000
    x, y, hag = rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(0, 30, n)
    low, high, west, east = hag < 5, hag > 25, x < -1, x > 1
    lost_low = lost_high = lost_side = 0
    for seed in range(40):
        keep = occlude(x, y, hag, np.random.default_rng(seed))
        assert keep.dtype == bool and keep.shape == (n,) and keep.any()
        lost_low += 1 - keep[low].mean()
        lost_high += 1 - keep[high].mean()
        lost_side += abs(keep[west].mean() - keep[east].mean())
    # the foot loses more than the top; some draws hide one side far more than the other
    assert lost_low > 2 * lost_high and lost_side / 40 > 0.15


def test_fit_separates_separable_descriptors():
    rng = np.random.default_rng(0)
    n = len(DESCRIPTOR_NAMES)
    desc = np.r_[rng.normal(0, 1, (200, n)), rng.normal(3, 1, (40, n))]
    label = np.r_[np.zeros(200, int), np.ones(40, int)]
    from towerpipe.towers.shape import ShapeVerifier

    v = ShapeVerifier(fit_verifier(desc, label, {"epochs": 100}))
    score = v.score_descriptors(desc)
    assert (score[label == 1] > 0.5).mean() > 0.95 and (score[label == 0] < 0.5).mean() > 0.95


def test_train_verifier_writes_a_verifier_and_its_card(tmp_path):
    paths = make_tiles(tmp_path / "tiles", n_blocks=5)
    out = train_verifier(paths, tmp_path / "towerpipe-verifier-v9", {"epochs": 50, "peak_view": False})
    data = json.loads((out / VERIFIER_FILE).read_text())
    card = data["card"]
    assert card["name"] == "towerpipe-verifier-v9" and card["descriptor"] == list(DESCRIPTOR_NAMES)
    assert card["objects"]["towers_by_family"] == {"synthetic": 20}  # 10 towers x 2 copies
    # the held-out block's towers are found, and its other objects are not (measured: 4 of 4, 0 of 53)
    val = card["validation"]
    assert val["towers"] >= 3 and val["tower_recall"] >= 0.75 and val["false_positive_rate"] <= 0.05
    assert "Held-out blocks" in (out / "MODEL_CARD.md").read_text()
    v = load_verifier(out)
    assert v.name == "towerpipe-verifier-v9"
    # leaving out the only family there is leaves no tower to learn from: said, not trained
    with pytest.raises(ConfigError, match="not both towers"):
        train_verifier(paths, tmp_path / "none", {"epochs": 5, "exclude_families": ["synthetic"]})
