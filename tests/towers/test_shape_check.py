"""The shape check of a cluster and the rules that amend it (:mod:`towerpipe.towers.shape_check`):
the score needed (rule 13), the parts judged instead, the conductors' vouch (rule 12) and the bare
score (rule 18)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

import towerpipe.towers.shape_check as sc
from conftest import tower_rules
from towerpipe.towers.shape_check import ShapeVerdict, shape_check

#: A 2 x 2 m footprint and the points of a 30 m object on it.
FOOTPRINT = shapely.box(0.0, 0.0, 2.0, 2.0)
HAG = np.linspace(0.0, 30.0, 60)
ARR = {"x": np.full(60, 1.0), "y": np.full(60, 1.0), "z": HAG + 100.0, "hag": HAG}


class _ByCount:
    """A verifier whose score is ``whole`` for the object's 60 points and ``fewer`` for fewer."""

    def __init__(self, whole: float, fewer: float = 1.0):
        self.whole, self.fewer = whole, fewer

    def score(self, x, y, hag):
        return self.whole if len(x) == 60 else self.fewer


def judge(verifier, *, tall=False, is_rescue=False, parts=(), arr=ARR, **rules) -> tuple[ShapeVerdict, int]:
    """The verdict, and how many times the split was asked for."""
    asked = []

    def split():
        asked.append(1)
        return list(parts)

    rules.setdefault("min_bare_score", 0.0)
    v = shape_check(
        verifier,
        tower_rules(**rules),
        FOOTPRINT,
        arr,
        None,
        HAG,
        (1.0, 1.0),
        tall=tall,
        is_rescue=is_rescue,
        split=split,
    )
    return v, len(asked)


def test_a_cluster_shaped_like_a_tower_passes_and_is_never_split():
    v, asked = judge(_ByCount(0.99), min_shape_score=0.95)
    assert (v.failed, v.shape, v.vouch, asked, v.view) == (None, 0.99, None, 0, "object")


def test_a_cluster_shaped_like_a_tree_fails_and_its_parts_are_judged_instead():
    v, asked = judge(_ByCount(0.4), min_shape_score=0.95, parts=["part"], vouch_height=0.0)
    assert (v.failed, v.value, list(v.parts), asked) == ("shape", 0.4, ["part"], 1)


@pytest.mark.parametrize(("tall", "failed"), [(True, None), (False, "shape")])
def test_rule_13_a_tall_cluster_passes_at_the_lower_score(tall, failed):
    v, _ = judge(_ByCount(0.93), tall=tall, min_shape_score=0.95, tall_shape_score=0.9, vouch_height=0.0)
    assert v.failed == failed


def test_a_rescue_without_an_object_fails_an_ordinary_cluster_passes():
    far = {k: (a + 50.0 if k in ("x", "y") else a) for k, a in ARR.items()}  # nothing under the footprint
    assert judge(_ByCount(1.0), is_rescue=True, arr=far)[0].failed == "shape"
    v, _ = judge(_ByCount(1.0), arr=far)
    assert v.failed is None and np.isnan(v.shape)


@pytest.mark.parametrize(
    ("parts", "is_rescue", "vouch"), [((), False, 0.8), (("part",), False, None), ((), True, None)]
)
def test_rule_12_conductors_vouch_only_for_a_cluster_with_no_part_to_judge(monkeypatch, parts, is_rescue, vouch):
    monkeypatch.setattr(sc, "vouching_support", lambda *a, **kw: 0.8)
    v, _ = judge(_ByCount(0.1), parts=parts, is_rescue=is_rescue)
    assert v.vouch == vouch
    assert v.failed == (None if vouch else "shape")


@pytest.mark.parametrize(
    ("bare", "min_bare_score", "failed"), [(0.05, 0.2, "bare"), (0.5, 0.2, None), (0.05, 0.0, None)]
)
def test_rule_18_a_cluster_that_scores_as_a_tower_only_with_its_conductors_fails(
    monkeypatch, bare, min_bare_score, failed
):
    monkeypatch.setattr(sc, "bare_score", lambda verifier, arr, obj: bare)
    v, asked = judge(_ByCount(0.99), min_shape_score=0.95, min_bare_score=min_bare_score, parts=["part"])
    assert v.failed == failed
    assert asked == (1 if failed else 0)


def test_a_tower_among_painted_crowns_is_judged_in_its_core_around_its_top():
    """The footprint takes in a crown 10 m from the tower: the whole object scores as a canopy,
    the core around the cluster's top (the tower's 60 points) as a tower, and the higher counts;
    rule 18 then reads the view that scored."""
    crown = np.random.default_rng(0).uniform([8.0, 8.0, 6.0], [12.0, 12.0, 14.0], (200, 3))
    arr = {k: np.r_[ARR[k], v] for k, v in zip(("x", "y", "hag"), crown.T, strict=True)}
    arr["z"] = arr["hag"] + 100.0
    wide = shapely.box(0.0, 0.0, 12.0, 12.0)
    seen = []

    class _TowerAlone:
        def score(self, x, y, hag):
            seen.append(len(x))
            return 0.99 if len(x) == 60 else 0.05

    def check(top, **rules):
        rules = tower_rules(**{"min_shape_score": 0.95, "min_bare_score": 0.0, **rules})
        return shape_check(
            _TowerAlone(), rules, wide, arr, None, HAG, (1.0, 1.0), tall=False, is_rescue=False, split=list, top=top
        )

    assert (check(None).failed, check(None).shape) == ("shape", 0.05)  # the whole object only
    v = check((1.0, 1.0))
    assert (v.failed, v.shape, len(v.obj)) == (None, 0.99, 260)  # the core decides; the object stays whole
    assert v.view == "core"  # and the tower's record says so (its shape_view)
    seen.clear()
    assert check((1.0, 1.0), min_bare_score=0.2).failed is None and seen == [260, 60, 60]  # rule 18 on the core


def test_a_cluster_its_core_passed_is_split_once_when_rule_18_drops_it(monkeypatch):
    """The split found no part before the core was judged: rule 18 dropping the cluster then reports
    that answer instead of asking the split again."""
    monkeypatch.setattr(sc, "core_object", lambda top, x, y, hag: np.arange(30))
    monkeypatch.setattr(sc, "bare_score", lambda verifier, arr, obj: 0.05)
    asked = []

    def split():
        asked.append(1)
        return []

    rules = tower_rules(min_shape_score=0.95, min_bare_score=0.2)
    v = shape_check(
        _ByCount(0.1),
        rules,
        FOOTPRINT,
        ARR,
        None,
        HAG,
        (1.0, 1.0),
        tall=False,
        is_rescue=False,
        split=split,
        top=(1.0, 1.0),
    )
    assert (v.failed, v.shape, list(v.parts), len(asked)) == ("bare", 1.0, [], 1)


def test_position_share_is_uniform_and_a_property_of_each_point_alone():
    rng = np.random.default_rng(0)
    x, y, z = 400_000 + rng.uniform(0, 500, 20_000), 4_600_000 + rng.uniform(0, 500, 20_000), rng.uniform(0, 60, 20_000)
    u = sc.position_share(x, y, z)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert np.histogram(u, bins=10, range=(0, 1))[0].min() > 1_800  # 2,000 expected in each tenth
    order = rng.permutation(len(x))[:5_000]  # another subset, in another order: the same numbers
    np.testing.assert_array_equal(sc.position_share(x[order], y[order], z[order]), u[order])
    # a millimetre apart is another point
    assert not np.array_equal(sc.position_share(x + 0.001, y, z), u)


def test_the_verifier_reads_a_dense_tiles_object_thinned_to_the_density_it_learned():
    rng = np.random.default_rng(1)
    n = 4_000
    arr = {"x": rng.uniform(0, 2, n), "y": rng.uniform(0, 2, n), "z": rng.uniform(100, 130, n), "density": 28.0}
    obj = np.arange(0, n, 2)
    # no density set, or a tile no denser than it: the whole object
    np.testing.assert_array_equal(sc.verifier_view(arr, obj, None), obj)
    np.testing.assert_array_equal(sc.verifier_view({**arr, "density": 14.0}, obj, 14.0), obj)
    np.testing.assert_array_equal(sc.verifier_view({k: v for k, v in arr.items() if k != "density"}, obj, 14.0), obj)
    seen = sc.verifier_view(arr, obj, 14.0)
    assert set(seen) <= set(obj) and abs(len(seen) / len(obj) - 0.5) < 0.05
    # the points a tile keeps of an object are those another tile (or run) keeps of it
    np.testing.assert_array_equal(sc.verifier_view(arr, obj[::-1], 14.0), seen[::-1])


def test_the_shape_check_scores_the_thinned_object_and_reports_it_whole():
    dense = {**ARR, "density": 40.0}
    seen = sc.verifier_view(dense, np.arange(60), 10.0)
    assert 0 < len(seen) < 60
    # the verifier sees fewer than the 60 points (scored 1.0), the verdict holds the whole object
    v, _ = judge(_ByCount(0.1), arr=dense, verifier_density=10.0)
    assert v.failed is None and v.shape == 1.0 and len(v.obj) == 60
    v, _ = judge(_ByCount(0.1), arr=dense)  # the shipped setting, 14 pts/m²
    assert v.failed is None
    v, _ = judge(_ByCount(0.1), arr=dense, verifier_density=None)  # null reads every object whole
    assert v.failed == "shape" and v.shape == 0.1
