"""Tests of towerpipe.towers.shape: the shape descriptor, the verifier, and the shape rule of
the tower extraction, with rule 12 (the conductors vouch for a tower the shape rule drops)."""

from __future__ import annotations

import json
from functools import partial

import numpy as np
import pytest
import shapely
from test_towers import BOUNDS, X0, Y0, pred_pair, synthetic_tower
from test_wires import spans

from conftest import UAV_TOWERS, extract, tower_rules
from towerpipe.errors import ModelError
from towerpipe.towers.conductor_rules import needed_vouch_height
from towerpipe.towers.shape import (
    DESCRIPTOR_NAMES,
    PEAK_CORE_RADIUS,
    VERIFIER_FILE,
    ShapeVerifier,
    core_object,
    load_verifier,
    object_points,
    peak_objects,
    peak_scores,
    resolve_verifier,
    shape_descriptor,
    unique_rows,
)


@pytest.mark.parametrize(
    ("n", "k", "span"),
    [(0, 3, 5), (1, 3, 5), (50, 3, 2), (2000, 3, 40), (3000, 2, 400), (9, 3, 10**9), (5, 1, 3)],
)
def test_unique_rows_is_numpy_row_unique_in_the_same_order(n, k, span):
    """The descriptor's voxels come out as ``np.unique(axis=0)`` gives them, row for row (every
    sum over them rounds the same), also when no integer key fits (the largest span)."""
    cells = np.random.default_rng(n + k).integers(-span, span, (n, k))
    np.testing.assert_array_equal(unique_rows(cells), np.unique(cells, axis=0))
    assert unique_rows(cells).dtype == np.int64


def tree(cx: float, cy: float, *, height: float = 12.0, crown: float = 3.5, n: int = 600, seed: int = 0):
    """Points of a tree as a flight sees it: a crown cap (most returns) and a few on the trunk; (x, y, hag)."""
    rng = np.random.default_rng(seed)
    phi, u = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.0, 1.0, n)
    r = crown * np.sqrt(u)
    h = height - (height * 0.45) * u**1.5 + rng.normal(0, 0.2, n)
    trunk = rng.uniform(0.5, height * 0.5, n // 20)
    x = np.r_[cx + r * np.cos(phi), cx + rng.normal(0, 0.15, trunk.size)]
    y = np.r_[cy + r * np.sin(phi), cy + rng.normal(0, 0.15, trunk.size)]
    return x, y, np.r_[h, trunk]


def test_descriptor_names_and_invariance_to_place_and_heading():
    xyz, hag = synthetic_tower(0.0, 0.0, seed=3)
    d = shape_descriptor(xyz[:, 0], xyz[:, 1], hag)
    assert d.shape == (len(DESCRIPTOR_NAMES),) and np.isfinite(d).all()
    # far away in a projected CRS: the same object (the voxel grid is relative to its centre)
    far = shape_descriptor(xyz[:, 0] + 712_345.0, xyz[:, 1] + 6_301_234.0, hag)
    np.testing.assert_allclose(far, d, atol=1e-6)
    # turned about the vertical: the same object up to the voxel grid
    a = np.deg2rad(37.0)
    xr = np.cos(a) * xyz[:, 0] - np.sin(a) * xyz[:, 1]
    yr = np.sin(a) * xyz[:, 0] + np.cos(a) * xyz[:, 1]
    turned = shape_descriptor(xr, yr, hag)
    i = DESCRIPTOR_NAMES.index
    for name in ("log_height", "height_continuity", "band0_share", "band4_share", "verticality"):
        assert turned[i(name)] == pytest.approx(d[i(name)], abs=0.05), name


def test_descriptor_does_not_hang_on_the_order_of_the_points():
    """The shape gate finds an object's points through a k-d tree, in the tree's order: the
    descriptor is the same (to rounding) in any order."""
    xyz, hag = synthetic_tower(0.0, 0.0, height=24.0, seed=4)
    d = shape_descriptor(xyz[:, 0], xyz[:, 1], hag)
    p = np.random.default_rng(0).permutation(len(hag))
    np.testing.assert_allclose(shape_descriptor(xyz[p, 0], xyz[p, 1], hag[p]), d, rtol=0, atol=1e-12)
    x, y, h = tree(3.0, -2.0)
    q = np.random.default_rng(1).permutation(len(h))
    np.testing.assert_allclose(shape_descriptor(x[q], y[q], h[q]), shape_descriptor(x, y, h), rtol=0, atol=1e-12)


def test_descriptor_tells_a_lattice_from_a_crown():
    xyz, hag = synthetic_tower(0.0, 0.0, height=24.0, seed=1)
    tower = shape_descriptor(xyz[:, 0], xyz[:, 1], hag)
    crown = shape_descriptor(*tree(0.0, 0.0))
    i = DESCRIPTOR_NAMES.index
    # a tower is seen from the ground to its top; a crown is a closed cap high up
    assert tower[i("height_continuity")] > crown[i("height_continuity")]
    assert tower[i("band0_share")] > crown[i("band0_share")]
    assert tower[i("plan_fill")] < crown[i("plan_fill")]


def test_descriptor_barely_moves_with_density():
    """Computed on occupied voxels: a tower thinned to a third keeps its descriptor's main entries."""
    xyz, hag = synthetic_tower(0.0, 0.0, height=30.0, step=0.1, seed=2)
    keep = np.random.default_rng(0).random(len(hag)) < 0.33
    full, thin = shape_descriptor(xyz[:, 0], xyz[:, 1], hag), shape_descriptor(xyz[keep, 0], xyz[keep, 1], hag[keep])
    i = DESCRIPTOR_NAMES.index
    for name in ("log_height", "band0_radius_rel", "band2_radius_rel", "log_plan_major", "verticality"):
        assert thin[i(name)] == pytest.approx(full[i(name)], abs=0.1), name


def test_object_points_are_those_near_the_footprint():
    foot = shapely.box(0, 0, 4, 4)
    x = np.array([2.0, 4.9, 5.5, -0.5, 10.0])
    y = np.array([2.0, 2.0, 2.0, -0.5, 10.0])
    assert object_points(foot, x, y).tolist() == [0, 1, 3]


def _verifier(bias: float) -> ShapeVerifier:
    """A verifier that gives every object the same score (sigmoid of ``bias``)."""
    n = len(DESCRIPTOR_NAMES)
    return ShapeVerifier({"mean": [0.0] * n, "std": [1.0] * n, "layers": [[[[0.0] * n], [bias]]]}, {"name": "const"})


def test_verifier_scores_and_file(tmp_path):
    v = _verifier(2.0)
    assert v.score(*tree(0.0, 0.0)) == pytest.approx(1 / (1 + np.exp(-2.0)))
    (tmp_path / VERIFIER_FILE).write_text(
        json.dumps(
            {
                "card": {"name": "const"},
                "weights": {
                    "mean": v.mean.tolist(),
                    "std": v.std.tolist(),
                    "layers": [[w.tolist(), b.tolist()] for w, b in v.layers],
                },
            }
        )
    )
    assert load_verifier(tmp_path).name == "const"
    assert load_verifier("none") is None and resolve_verifier("none") is None
    with pytest.raises(ModelError, match="towers.verifier: none"):
        load_verifier(tmp_path / "absent")
    with pytest.raises(ValueError, match="retrain"):
        ShapeVerifier({"mean": [0.0], "std": [1.0], "layers": []})


def test_shape_rule_drops_what_the_verifier_rejects(tmp_path, monkeypatch):
    """With a context, each tower gets the verifier's score of the object under it; towers below
    ``min_shape_score`` are dropped; without a context the score is unknown and never drops."""
    import towerpipe.towers.extract as ex

    xyz, hag = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    pair = pred_pair(xyz, hag, 0.95, ["b1"])
    ctx = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": hag.astype(np.float64)}

    def context(cx, cy):
        return ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)

    for bias, kept in ((-3.0, 0), (3.0, 1)):
        monkeypatch.setattr(ex, "load_verifier", lambda spec, b=bias: _verifier(b))
        found = extract([pair], "b1", BOUNDS, zone="z1", context=context, min_shape_score=0.5).towers
        assert len(found) == kept
    scored = extract([pair], "b1", BOUNDS, zone="z1", context=context, min_shape_score=0.0).towers
    assert scored["shape_score"].iloc[0] == pytest.approx(1 / (1 + np.exp(-3.0)), abs=1e-3)  # 3 decimals
    plain = extract([pair], "b1", BOUNDS, zone="z1", min_shape_score=0.5).towers
    assert len(plain) == 1 and plain["shape_score"].isna().all() and plain["shape_view"].isna().all()


class _NarrowVerifier:
    """Tower-like when the object is at most 9 m across in y and at most half as wide as it is
    high (a stand-in for the network: a crown, or the core of one, is wider)."""

    def score(self, x, y, hag):
        return float(np.ptp(y) <= 9.0 and max(np.ptp(x), np.ptp(y)) <= 0.5 * np.ptp(hag))


def test_a_tower_among_painted_crowns_is_split_from_them(monkeypatch):
    """A crown touching a tower, painted at 0.6 by the segmenter, makes one cluster with it and the
    object under that cluster is rejected; clustered again from its points at or above 0.7, the
    tower stands alone and passes. Without a split (no part to judge) the core of the object
    around the cluster's top passes the whole cluster."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _NarrowVerifier())
    t_xyz, t_hag = synthetic_tower(X0 + 50, Y0 + 50, seed=2)
    cx, cy, ch = tree(X0 + 50, Y0 + 50 + 7.4, height=12.0, seed=3)
    c_xyz = np.c_[cx, cy, 100.0 + ch]
    xyz, hag = np.r_[t_xyz, c_xyz], np.r_[t_hag, ch].astype(np.float32)
    prob = np.r_[np.full(len(t_xyz), 0.95), np.full(len(c_xyz), 0.6)]
    pair = pred_pair(xyz, hag, prob, ["b1"])
    ctx = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": hag.astype(np.float64)}

    def context(cx, cy):
        return ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)

    # nor rule 23: this verifier passes the crown's part too, where the shipped one rejects it
    no_split = {"split_thresholds": [], "split_linkage": 0, "peak_share": 0}
    whole = extract([pair], "b1", BOUNDS, zone="z1", context=context, min_shape_score=0.5, **no_split)
    ((_, idx),) = whole.members.values()
    assert len(whole.towers) == 1 and set(range(len(t_xyz))) <= set(idx.tolist())
    assert whole.towers["shape_view"].tolist() == ["core"]  # its record says which view passed it
    found = extract([pair], "b1", BOUNDS, zone="z1", context=context, min_shape_score=0.5, split_thresholds=[0.7])
    assert len(found.towers) == 1
    ((blocks, idx),) = found.members.values()
    assert set(idx.tolist()) == set(range(len(t_xyz)))  # the tower's points, none of the crown's
    assert found.towers["shape_score"].iloc[0] == 1.0 and found.towers["shape_view"].tolist() == ["object"]


@pytest.mark.parametrize("split_linkage", [0.0, 1.5])
@pytest.mark.parametrize("prob", [0.95, 0.2])
def test_a_tower_painted_like_the_crown_beside_it_is_parted_by_a_tighter_linkage(monkeypatch, split_linkage, prob):
    """A crown 2 m from a tower (within ``towers.linkage``, 2.5 m, and beyond 1.5 m), painted as
    the tower is: no split threshold parts them, the object under the cluster is rejected. Linked
    again at ``split_linkage`` the tower stands alone and passes with exactly its own points;
    without that step the core view passes the tower with the crown. The same when both are
    painted faintly and the rescue (rule 10) finds them."""
    from scipy.spatial import cKDTree

    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _NarrowVerifier())
    t_xyz, t_hag = synthetic_tower(X0 + 50, Y0 + 50, seed=2)
    cx, cy, ch = tree(X0 + 50, Y0 + 50 + 7.5, height=14.0, seed=3)
    c_xyz = np.c_[cx, cy, 100.0 + ch]
    gap = cKDTree(t_xyz).query(c_xyz)[0].min()
    assert 1.5 < gap < 2.5 and cKDTree(t_xyz[:, :2]).query(c_xyz[:, :2])[0].min() > 1.0  # no footprint merge
    xyz, hag = np.r_[t_xyz, c_xyz], np.r_[t_hag, ch].astype(np.float32)
    pair = pred_pair(xyz, hag, prob, ["b1"])
    ctx = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": hag.astype(np.float64)}

    def context(x, y):
        return ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)

    kw = {"zone": "z1", "context": context, "min_shape_score": 0.5, "split_thresholds": [0.5, 0.7]}
    kw |= {"threshold": 0.3, "rescue_threshold": 0.1}  # 0.2: the rescue's
    kw["peak_share"] = 0  # nor rule 23: this verifier passes the crown's part too, the shipped one not
    found = extract([pair], "b1", BOUNDS, **kw, split_linkage=split_linkage)
    ((_, idx),) = found.members.values()
    if split_linkage:
        assert set(idx.tolist()) == set(range(len(t_xyz))) and found.towers["shape_view"].tolist() == ["object"]
    else:
        assert len(idx) > len(t_xyz) and found.towers["shape_view"].tolist() == ["core"]


def _pole(cx: float, cy: float, n: int, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A thin pole of ``n`` points standing 1-12 m high (absolute z 100 m above its hag); (xyz, hag)."""
    rng = np.random.default_rng(seed)
    hag = np.linspace(1.0, 12.0, n)
    return np.c_[cx + rng.normal(0, 0.1, n), cy + rng.normal(0, 0.1, n), 100.0 + hag], hag


@pytest.mark.parametrize(("min_split_points", "towers"), [(20, 0), (15, 1)])
def test_a_splits_parts_need_min_split_points(monkeypatch, min_split_points, towers):
    """A wide crown painted at 0.6 with a thin 16-point spike in it painted at 0.9: split at 0.7, the
    spike alone is narrow enough to pass the shape check. Under ``min_split_points`` it is no part,
    and nothing is reported; the same spike standing alone is a tower of ``min_points`` 15."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _NarrowVerifier())
    p_xyz, p_hag = _pole(X0 + 50, Y0 + 50, 16)
    cx, cy, ch = tree(X0 + 50, Y0 + 50, height=11.0, crown=7.0, n=1500, seed=3)
    xyz = np.r_[p_xyz, np.c_[cx, cy, 100.0 + ch]]
    hag = np.r_[p_hag, ch].astype(np.float32)
    prob = np.r_[np.full(len(p_xyz), 0.9), np.full(len(cx), 0.6)]
    ctx = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": hag.astype(np.float64)}

    def context(x, y):
        return ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)

    rules = {"min_shape_score": 0.5, "split_thresholds": [0.7], "min_points": 15}
    kw = {"zone": "z1", "context": context, **rules, "min_split_points": min_split_points}
    found = extract([pred_pair(xyz, hag, prob, ["b1"])], "b1", BOUNDS, **kw)
    assert len(found.towers) == towers
    alone = extract([pred_pair(p_xyz, p_hag.astype(np.float32), prob[: len(p_xyz)], ["b1"])], "b1", BOUNDS, **kw)
    assert len(alone.towers) == 1 and int(alone.towers["n_points"].iloc[0]) == 16


def _faint_scene():
    """A confident tower, a faint one (a thin lattice the segmenter paints at 0.15-0.25, its
    halo at 0.12) and a faint crown, 100 m apart; (pair, context, index ranges)."""
    a_xyz, a_hag = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    b_xyz, b_hag = synthetic_tower(X0 + 150, Y0 + 50, half_base=1.0, half_top=0.4, arm=2.0, seed=2)
    cx, cy, ch = tree(X0 + 250, Y0 + 50, height=14.0, crown=6.0, seed=3)
    c_xyz = np.c_[cx, cy, 100.0 + ch]
    rng = np.random.default_rng(4)
    # the confident tower's halo: points around its legs the segmenter is unsure of
    halo = a_xyz[::7] + np.r_[0.8, 0.0, 0.0]
    xyz = np.r_[a_xyz, halo, b_xyz, c_xyz]
    hag = np.r_[a_hag, halo[:, 2] - 100.0, b_hag, ch].astype(np.float32)
    prob = np.r_[
        np.full(len(a_xyz), 0.9),
        np.full(len(halo), 0.12),
        rng.uniform(0.15, 0.25, len(b_xyz)),
        np.full(len(c_xyz), 0.2),
    ]
    ends = np.cumsum([len(a_xyz), len(halo), len(b_xyz), len(c_xyz)])
    ctx = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": hag.astype(np.float64)}

    def context(x, y):
        return ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)

    return pred_pair(xyz, hag, prob, ["b1"]), context, ends


def test_rescue_finds_a_faint_tower_and_outlines_it(monkeypatch):
    """Rule 10: a tower painted below towers.threshold is found from the points at or above
    towers.rescue_threshold when the object is shaped like a tower, and reported with those
    points; a faint crown is not (the shape check decides), nor the halo of a tower already
    found (no second tower), nor a cluster whose highest probability stays under
    towers.min_core_prob, and without the shape check nothing is rescued."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _NarrowVerifier())
    pair, context, (a, halo, b, c) = _faint_scene()
    rules = {"context": context, "min_shape_score": 0.5, "threshold": 0.3, "split_thresholds": []}
    plain = extract([pair], "b1", BOUNDS, zone="z1", rescue_threshold=0.0, **rules)
    assert plain.towers["centroid_x"].round().tolist() == [X0 + 50]
    found = extract([pair], "b1", BOUNDS, zone="z1", rescue_threshold=0.1, point_threshold=0.1, **rules)
    assert sorted(found.towers["centroid_x"].round().tolist()) == [X0 + 50, X0 + 150]
    faint = found.towers.loc[found.towers["centroid_x"].round() == X0 + 150].iloc[0]
    ((_, idx),) = [m for tid, m in found.members.items() if tid == faint["tower_id"]]
    assert set(idx.tolist()) == set(range(halo, b))  # the faint tower's points, all of them
    assert faint["prob_max"] < 0.3 and faint["shape_score"] == 1.0
    # its highest probability must reach min_core_prob: a cluster painted only faintly stays out
    assert len(extract([pair], "b1", BOUNDS, zone="z1", rescue_threshold=0.1, min_core_prob=0.3, **rules).towers) == 1
    # rule 21: the faint tower is 30 m high, so towers.tall_core_prob is its bar; the 14 m crown's stays 0.3
    tall = {"rescue_threshold": 0.1, "min_core_prob": 0.3, "tall_core_prob": 0.2, **rules}
    assert len(extract([pair], "b1", BOUNDS, zone="z1", **tall).towers) == 2
    assert len(extract([pair], "b1", BOUNDS, zone="z1", **{**tall, "wire_min_height": 35.0}).towers) == 1
    arrays, meta = pair
    arrays = {**arrays, "prob": arrays["prob"].copy()}
    arrays["prob"][halo] = 0.5  # one confident point on the faint tower
    seeded = extract([(arrays, meta)], "b1", BOUNDS, zone="z1", rescue_threshold=0.1, min_core_prob=0.3, **rules)
    assert len(seeded.towers) == 2
    # no points around it to judge (the context knows nothing there): never rescued unjudged
    unjudged = extract([pair], "b1", BOUNDS, zone="z1", rescue_threshold=0.1, **{**rules, "context": lambda x, y: None})
    assert len(unjudged.towers) == 1
    # no shape check (no context): the rescue would only be a lower threshold, so it never runs
    blind = extract([pair], "b1", BOUNDS, zone="z1", rescue_threshold=0.1, threshold=0.3, split_thresholds=[])
    assert len(blind.towers) == 1


def test_rescue_threshold_is_calibrated_and_bounded():
    """The schema's default is the calibrated one; a value not below towers.threshold is off."""
    from conftest import tower_rules
    from towerpipe.errors import ConfigError

    assert tower_rules().rescue_threshold == 0.1
    with pytest.raises(ConfigError, match="towers.rescue_threshold"):
        tower_rules(rescue_threshold=1.5)


@pytest.mark.shared
def test_shipped_verifier_knows_real_towers_from_real_trees():
    """The shipped verifier as shipped, on real objects: real UAV lattice towers score high, the
    real trees of an IGN tile (class 1 there) low. Both are in its training zones (other copies
    and placements); what it does on real shapes and trees it never saw is measured by leaving
    them out (docs/model.md, the shape verifier)."""
    import laspy

    from conftest import RGB_SUBSET
    from towerpipe.inference.candidates import height_peaks
    from towerpipe.synth.real import airborne_resample, load_real_towers

    v = load_verifier("shipped")
    rng = np.random.default_rng(0)
    towers = []
    for name, xyz in load_real_towers(UAV_TOWERS.parent):
        if name.startswith("uav:"):
            p = airborne_resample(xyz, 10.0, rng)  # what a flight at 10 pts/m² sees of it
            towers.append(v.score(p[:, 0], p[:, 1], p[:, 2] - p[:, 2].min()))
    las = laspy.read(RGB_SUBSET)
    x, y, z, cls = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z), np.asarray(las.classification)
    g = cls == 2
    from scipy.interpolate import griddata

    hag = z - griddata(np.c_[x[g], y[g]], z[g], np.c_[x, y], method="nearest")
    veg = (cls == 1) & (hag >= 0.5)
    _, peaks, _ = height_peaks(x[veg], y[veg], hag[veg], min_height=10.0)
    trees = []
    for cx, cy in peaks:
        near = np.flatnonzero(veg & (np.hypot(x - cx, y - cy) < 4.0))
        idx = object_points(shapely.convex_hull(shapely.multipoints(np.c_[x[near], y[near]])), x[veg], y[veg])
        trees.append(v.score(x[veg][idx], y[veg][idx], hag[veg][idx]))
    assert len(towers) >= 16 and len(trees) >= 4
    assert np.mean(np.asarray(towers) >= 0.5) >= 0.75, towers
    assert np.mean(np.asarray(trees) >= 0.5) <= 0.1, trees


@pytest.mark.shared
def test_shape_gate_keeps_the_peak_of_a_real_tower_among_trees():
    """The shape gate of the inference (:func:`peak_scores`, shipped verifier): the peak of a
    real UAV lattice tower thinned as a flight sees it keeps its window at the default gate
    of the schema, the peaks of a stand of trees beside it do not."""
    from conftest import schema_config
    from towerpipe.inference.candidates import height_peaks
    from towerpipe.synth.real import airborne_resample, load_real_towers

    gate = schema_config()["inference"]["shape_gate"]
    v = load_verifier("shipped")
    rng = np.random.default_rng(1)
    name, xyz = next((n, p) for n, p in load_real_towers(UAV_TOWERS.parent) if n.startswith("uav:"))
    p = airborne_resample(xyz, 10.0, rng)
    xs, ys, hs = [p[:, 0] - p[:, 0].mean()], [p[:, 1] - p[:, 1].mean()], [p[:, 2] - p[:, 2].min()]
    for k, (cx, cy) in enumerate([(30, 0), (45, 3), (30, 20), (55, -15), (-30, 25)]):
        tx, ty, th = tree(cx, cy, height=14.0 + k, seed=k)
        xs.append(tx), ys.append(ty), hs.append(th)
    x, y, hag = np.concatenate(xs), np.concatenate(ys), np.concatenate(hs)
    _, centres, _ = height_peaks(x, y, hag, min_height=10.0)
    scores = peak_scores(v, peak_objects(centres, x, y, hag), x, y, hag)
    at_tower = np.hypot(centres[:, 0], centres[:, 1]) < 8.0
    assert at_tower.sum() >= 1 and (~at_tower).sum() >= 4, centres
    assert scores[at_tower].max() >= gate, (name, scores)
    assert (scores[~at_tower] < gate).all(), scores


def _judged(verifier, rules, arr, cluster, top):
    """What the shape check says of a cluster (its points' indices in ``arr``) topped at ``top``."""
    from towerpipe.towers.shape_check import shape_check

    fp = shapely.convex_hull(shapely.multipoints(np.c_[arr["x"][cluster], arr["y"][cluster]]))
    kw = {"tall": False, "is_rescue": False, "split": list, "top": top}
    return shape_check(verifier, rules, fp, arr, None, arr["hag"][cluster], (0.0, 0.0), **kw).failed


@pytest.mark.shared
def test_the_shape_check_finds_a_real_tower_painted_with_crowns_by_its_core():
    """A real UAV lattice (scaled to 14-15 m, 6 pts/m²) ringed by six crowns that reach within
    4.5 m of its axis, the segmenter having painted the lattice and the crowns' inner halves: the
    object under that cluster is a canopy to the shipped verifier, the core around the cluster's
    top (:data:`PEAK_CORE_RADIUS`) passes the check for most towers. A crown's own cluster fails in
    both views."""
    from conftest import tower_rules
    from towerpipe.synth.real import airborne_resample, load_real_towers

    v, rules = load_verifier("shipped"), tower_rules()
    ring = 8.0 * np.c_[np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)]
    whole, core, crowns = [], [], []
    for xyz in [p for n, p in load_real_towers(UAV_TOWERS.parent) if n.startswith("uav:")][:10]:
        p = airborne_resample(xyz * (16.0 / np.ptp(xyz[:, 2])), 6.0, np.random.default_rng(1))
        xs, ys, hs = [p[:, 0] - p[:, 0].mean()], [p[:, 1] - p[:, 1].mean()], [p[:, 2] - p[:, 2].min()]
        for k, (cx, cy) in enumerate(ring):
            tx, ty, th = tree(cx, cy, height=float(hs[0].max()) - 5 + k % 2, seed=k)
            xs.append(tx), ys.append(ty), hs.append(th)
        x, y, hag = np.concatenate(xs), np.concatenate(ys), np.concatenate(hs)
        arr, n = {"x": x, "y": y, "z": hag + 100.0, "hag": hag}, len(xs[0])
        judge = partial(_judged, v, rules, arr)
        painted = np.flatnonzero(np.r_[np.ones(n, bool), np.hypot(x[n:], y[n:]) < 6.0])
        top = (float(x[np.argmax(hs[0])]), float(y[np.argmax(hs[0])]))
        whole.append(judge(painted, None)), core.append(judge(painted, top))
        for k in range(len(ring)):
            own = n + sum(len(a) for a in xs[1 : k + 1]) + np.arange(len(xs[k + 1]))
            crowns.append(judge(own, (float(x[own][np.argmax(hag[own])]), float(y[own][np.argmax(hag[own])]))))
    assert whole == ["shape"] * 10, whole
    assert core.count(None) >= 6, core
    assert crowns == ["shape"] * len(crowns), crowns


def test_the_core_of_an_object_is_its_peak_object_within_the_core_radius():
    x, y, hag = (np.r_[a, b] for a, b in zip(tree(0.0, 0.0, seed=1), tree(9.0, 0.0, seed=2), strict=True))
    for top in [(0.2, -0.1), (9.0, 0.5), (4.5, 0.0)]:
        want = peak_objects(np.array([top]), x, y, hag, radius=PEAK_CORE_RADIUS)[0]
        np.testing.assert_array_equal(core_object(top, x, y, hag), want)
    assert core_object((100.0, 100.0), x, y, hag) is None  # nothing around it


def test_peak_scores_of_a_peak_without_an_object_are_zero():
    v = _verifier(5.0)  # scores every object ~1
    x, y, hag = tree(0.0, 0.0)
    s = peak_scores(v, peak_objects(np.array([[0.0, 0.0], [100.0, 100.0]]), x, y, hag), x, y, hag)
    assert s[0] > 0.9 and s[1] == 0.0
    exclude = np.ones(len(x), bool)  # every point an overhead wire: no object anywhere
    objects = peak_objects(np.array([[0.0, 0.0]]), x, y, hag, exclude=exclude)
    assert (peak_scores(v, objects, x, y, hag) == 0).all()


# rule 12, the conductors' vouch (towers.vouch_height)
BASE_Z = 100.0  # flat ground: HAG is z - BASE_Z


class _Rejects:
    """A verifier that takes every object for a tree."""

    def score(self, x, y, hag):
        return 0.0


def strung_tower(wire_z: float | None = 28.0):
    """A 30 m tower at the block's centre with conductors strung through it ``wire_z`` m up (``None``:
    none): its points and heights, and the towers step's context of it and its wires."""
    rng = np.random.default_rng(2)
    cx, cy = X0 + 250, Y0 + 250
    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z, seed=3)
    wires = spans(cx, cy, BASE_Z + wire_z, rng) if wire_z is not None else np.empty((0, 3))
    ctx = {
        "x": np.r_[t_xyz[:, 0], wires[:, 0]],
        "y": np.r_[t_xyz[:, 1], wires[:, 1]],
        "z": np.r_[t_xyz[:, 2], wires[:, 2]],
        "hag": np.r_[t_hag, wires[:, 2] - BASE_Z].astype(np.float64),
    }
    return t_xyz, t_hag, lambda x, y: (ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700))


@pytest.mark.parametrize(("vouch_height", "kept"), [(0.0, 0), (5.0, 1), (12.0, 0)])
def test_conductors_vouch_for_a_tower_the_shape_check_drops(monkeypatch, vouch_height, kept):
    """A 30 m tower carrying conductors at 28 m, scored as a tree by the verifier: kept when its top
    stands ``vouch_height`` m above the wires in its ring (about 8 m here), dropped otherwise."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _Rejects())
    t_xyz, t_hag, context = strung_tower()
    rules = {"min_shape_score": 0.5, "split_thresholds": [], "vouch_height": vouch_height}
    found = extract([pred_pair(t_xyz, t_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", context=context, **rules)
    assert len(found.towers) == kept
    if kept:
        assert found.towers["shape_score"].iloc[0] == 0.0  # reported with the score it got
        assert found.towers["wire_support"].iloc[0] == 1.0


@pytest.mark.parametrize(
    ("score", "vouch_low_height", "kept"), [(0.8, 5.0, 1), (0.7, 5.0, 0), (0.8, 0.0, 0), (0.8, 12.0, 0)]
)
def test_conductors_vouch_a_few_metres_under_the_top_of_a_cluster_shaped_almost_as_a_tower(
    monkeypatch, score, vouch_low_height, kept
):
    """The same tower, about 8 m over the wires in its ring (under rule 12's 15 m), scored ``score``
    (under the shape check's 0.95): kept when it scores at least ``vouch_low_score`` (0.75) and
    stands ``vouch_low_height`` m over the wires; dropped scored 0.7, with the second height off (0),
    or with one higher than its top stands."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _Scores(score))
    t_xyz, t_hag, context = strung_tower()
    rules = {
        "min_shape_score": 0.95,
        "tall_shape_score": None,
        "split_thresholds": [],
        "vouch_height": 15.0,
        "vouch_low_height": vouch_low_height,
        "vouch_low_score": 0.75,
    }
    found = extract([pred_pair(t_xyz, t_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", context=context, **rules)
    assert len(found.towers) == kept
    if kept:
        assert found.towers["shape_score"].iloc[0] == pytest.approx(score)
        assert found.towers["wire_support"].iloc[0] == 1.0


def test_the_vouch_height_a_cluster_needs_by_its_shape_score():
    """Rule 12's height: the second one from ``vouch_low_score`` up (never above the first), the first
    under it or without a score; nothing when rule 12 is off."""
    rules = tower_rules(vouch_height=15.0, vouch_low_height=5.0, vouch_low_score=0.75)
    assert [needed_vouch_height(rules, s) for s in (0.75, 0.9, 0.74, float("nan"))] == [5.0, 5.0, 15.0, 15.0]
    assert needed_vouch_height(tower_rules(vouch_height=4.0, vouch_low_height=5.0, vouch_low_score=0.75), 0.9) == 4.0
    assert needed_vouch_height(tower_rules(vouch_height=15.0, vouch_low_height=0.0), 0.99) == 15.0
    assert needed_vouch_height(tower_rules(vouch_height=0.0, vouch_low_height=5.0, vouch_low_score=0.0), 0.99) == 0.0


def test_conductors_do_not_vouch_for_a_crown_under_them_or_for_unknown_support(monkeypatch):
    """A 14 m crown 40 m along the line, under conductors 20 m up, is not vouched for; nor is a
    tower whose ring lies outside the data (unknown support)."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _Rejects())
    rng = np.random.default_rng(4)
    cx, cy = X0 + 250, Y0 + 250
    wires = spans(cx - 40.0, cy, BASE_Z + 28.0, rng)
    n = 400
    r, a = 3.0 * np.sqrt(rng.random(n)), rng.uniform(0, 2 * np.pi, n)
    crown_hag = rng.uniform(6.0, 14.0, n)
    crown = np.c_[cx + r * np.cos(a), cy + r * np.sin(a), BASE_Z + crown_hag]
    ctx = {
        "x": np.r_[crown[:, 0], wires[:, 0]],
        "y": np.r_[crown[:, 1], wires[:, 1]],
        "z": np.r_[crown[:, 2], wires[:, 2]],
        "hag": np.r_[crown_hag, wires[:, 2] - BASE_Z],
    }
    rules = {"min_shape_score": 0.5, "split_thresholds": [], "vouch_height": 5.0, "min_height": 5.0}
    pair = pred_pair(crown, crown_hag.astype(np.float32), 0.95, ["b1"])
    found = extract(
        [pair], "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)), **rules
    )
    assert len(found.towers) == 0

    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z, seed=3)
    tower = {"x": t_xyz[:, 0], "y": t_xyz[:, 1], "z": t_xyz[:, 2], "hag": t_hag.astype(np.float64)}
    inside = (cx - 30, cy - 30, cx + 30, cy + 30)  # no data in the 80-160 m ring: support unknown
    pair = pred_pair(t_xyz, t_hag, 0.95, ["b1"])
    found = extract([pair], "b1", BOUNDS, zone="z1", context=lambda x, y: (tower, inside), **rules)
    assert len(found.towers) == 0


# rule 13, tall clusters (towers.tall_shape_score)
class _Scores:
    """A verifier that gives every object the same score."""

    def __init__(self, value: float):
        self.value = value

    def score(self, x, y, hag):
        return self.value


@pytest.mark.parametrize(
    ("tall_shape_score", "wire_z", "kept"),
    [(None, 28.0, 0), (0.9, 28.0, 1), (0.93, 28.0, 0), (0.9, None, 0)],
)
def test_a_tall_cluster_passes_the_shape_check_lower_with_conductors(monkeypatch, tall_shape_score, wire_z, kept):
    """A 30 m tower scored 0.92 (under ``min_shape_score`` 0.95): kept at ``tall_shape_score`` 0.9
    when conductors point at it, dropped by default, above 0.92, or without conductors (rule 7)."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _Scores(0.92))
    t_xyz, t_hag, context = strung_tower(wire_z)
    assert t_hag.max() >= 20.0  # the conductor rule's height (towers.wire_min_height)
    rules = {"min_shape_score": 0.95, "split_thresholds": [], "tall_shape_score": tall_shape_score}
    rules["min_wire_support"] = 0.5  # the schema's: the conductor rule judges the tall cluster
    rules["vouch_low_height"] = 0.0  # rule 13 alone: rule 12 would vouch for a tower scored 0.92
    found = extract([pred_pair(t_xyz, t_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", context=context, **rules)
    assert len(found.towers) == kept
    if kept:
        assert found.towers["shape_score"].iloc[0] == pytest.approx(0.92)
        assert found.towers["wire_support"].iloc[0] == 1.0


def test_a_low_cluster_needs_the_full_shape_score_whatever_the_tall_one():
    """A 14 m cluster scored 0.92 stays under ``min_shape_score`` (0.95) with ``tall_shape_score``
    0.9: rule 13 is for clusters the conductor rule judges (``towers.wire_min_height``, 15 m)."""
    import towerpipe.towers.extract as ex

    rng = np.random.default_rng(4)
    cx, cy = X0 + 250, Y0 + 250
    n = 400
    r, a = 1.0 * np.sqrt(rng.random(n)), rng.uniform(0, 2 * np.pi, n)
    hag = rng.uniform(0.5, 14.0, n)
    pole = np.c_[cx + r * np.cos(a), cy + r * np.sin(a), BASE_Z + hag]
    ctx = {"x": pole[:, 0], "y": pole[:, 1], "z": pole[:, 2], "hag": hag}
    rules = {"min_shape_score": 0.95, "split_thresholds": [], "tall_shape_score": 0.9, "min_height": 5.0}
    for score, kept in ((0.92, 0), (0.96, 1)):  # under the full score; the same cluster at it
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(ex, "load_verifier", lambda spec, score=score: _Scores(score))
            found = extract(
                [pred_pair(pole, hag.astype(np.float32), 0.95, ["b1"])],
                "b1",
                BOUNDS,
                zone="z1",
                context=lambda x, y: (ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)),
                **rules,
            )
        assert len(found.towers) == kept, score
