"""Tests of towerpipe.towers.column: the faint points of a tower's body that are reported."""

from __future__ import annotations

import numpy as np
from test_foot import lattice, shrubs
from test_towers import BOUNDS, X0, Y0, pred_pair

from conftest import extract

COLUMN = {"threshold": 0.1, "outside": 1.0, "min_height": 0.0}


def test_the_column_takes_faint_points_within_the_outline_not_beyond_it():
    from towerpipe.towers.column import column_mask

    tx, ty, _ = lattice()
    # inside the outline, 0.8 m beyond a face, 2 m beyond it, and inside but too faint
    x = np.array([0.0, 3.8, 5.0, 0.5])
    y = np.array([0.0, 0.0, 0.0, 0.5])
    prob = np.array([0.2, 0.15, 0.9, 0.05])
    hag = np.array([12.0, 12.0, 12.0, 12.0])
    assert column_mask(tx, ty, x, y, hag, prob, COLUMN).tolist() == [True, True, False, False]
    assert not column_mask(tx, ty, x, y, hag, prob, {**COLUMN, "threshold": 0.0}).any()  # off
    low = np.array([12.0, 5.0, 12.0, 12.0])  # the foot below min_height is not the column's
    assert column_mask(tx, ty, x, y, low, prob, {**COLUMN, "min_height": 8.0}).tolist() == [True, False, False, False]
    z = np.arange(0.0, 14.0, 0.5)  # the tower's points on a line outline nothing
    assert not column_mask(np.zeros_like(z), z, x, y, hag, prob, COLUMN).any()
    empty = np.empty(0)
    assert column_mask(tx, ty, empty, empty, empty, empty, COLUMN).shape == (0,)


def faint_lattice(cx: float, cy: float):
    """A lattice whose every third point the segmenter painted faintly (0.2), with a faint
    crown 4 m beyond a face: xyz, hag, single-view and view-mean probabilities, the tower's
    point count."""
    x, y, hag = lattice(seed=5)
    n = len(x)
    bx, by, bh = shrubs(7.0, 0.0, 1.0, n=80, top=12.0, seed=6)
    bh = bh + 6.0  # a crown 6-18 m up
    xyz = np.column_stack([np.r_[x, bx] + cx, np.r_[y, by] + cy, 100.0 + np.r_[hag, bh]])
    prob = np.full(len(xyz), 0.2, np.float32)
    prob[:n][np.arange(n) % 3 != 0] = 0.95
    return xyz, np.r_[hag, bh].astype(np.float32), prob, n


def test_a_tower_reports_the_faint_points_of_its_body_and_not_the_crown_beside_it():
    xyz, hag, prob, n = faint_lattice(X0 + 50, Y0 + 50)
    arrays, meta = pred_pair(xyz, hag, prob, ["b1"])
    arrays["prob_single"] = prob.copy()
    off = extract([(arrays, meta)], "b1", BOUNDS, zone="z1", column={**COLUMN, "threshold": 0.0})
    on = extract([(arrays, meta)], "b1", BOUNDS, zone="z1", column=COLUMN)
    assert len(off.towers) == len(on.towers) == 1  # the rule picks points, never towers
    strong = set(np.flatnonzero(prob[:n] >= 0.5).tolist())
    assert set(off.members[off.towers.iloc[0]["tower_id"]][1].tolist()) <= strong
    got = set(on.members[on.towers.iloc[0]["tower_id"]][1].tolist())
    assert len(got & set(range(n))) > 0.97 * n  # the faint third of the body is back
    assert not got & set(range(n, len(xyz)))  # the crown beside it is not
    assert on.towers.iloc[0]["n_points"] == len(got)
    assert on.towers.iloc[0]["footprint_area_m2"] == off.towers.iloc[0]["footprint_area_m2"]


def test_a_towers_column_is_judged_alike_by_both_blocks_it_touches():
    """Across a block edge, each block's job reports the same points of a faint tower,
    whatever the order of the prediction files."""
    edge = X0 + 250.0
    xyz, hag, prob, n = faint_lattice(edge + 0.6, Y0 + 100)
    west = xyz[:, 0] < edge
    pairs = []
    for side, name in ((west, "bw"), (~west, "be")):
        arrays, meta = pred_pair(xyz[side], hag[side], prob[side], [name], tile=name)
        arrays["prob_single"] = prob[side].copy()
        arrays["point_index"] = np.flatnonzero(side)
        pairs.append((arrays, meta))
    bw, be = (X0, Y0, edge, Y0 + 500), (edge, Y0, X0 + 500, Y0 + 500)
    a = extract(pairs, "bw", bw, zone="z1", column=COLUMN).members
    b = extract(pairs[::-1], "be", be, zone="z1", column=COLUMN).members
    assert a.keys() == b.keys() and len(a) == 1

    def points(members):
        ((blocks, idx),) = members.values()
        return sorted(zip(np.asarray(blocks).astype(str).tolist(), np.asarray(idx).tolist(), strict=True))

    assert points(a) == points(b)
    assert len({i for _, i in points(a)} & set(range(n))) > 0.97 * n


def test_the_schema_gives_the_column_and_the_foot_their_own_keys():
    from conftest import tower_rules

    rules = tower_rules()
    assert set(rules.column) == {"threshold", "outside", "min_height"}
    assert set(rules.foot) == {"height", "band", "inside", "outside", "outline_points"}
    # the foot judges below its height, the column above it
    assert rules.column["min_height"] >= rules.foot["height"]


def test_the_column_takes_no_point_from_a_block_the_tower_does_not_touch():
    """A tower wholly in one block, with faint points just across the edge: the neighbour's
    job does not judge that tower (its cluster does not touch the neighbour), so the neighbour's
    merge would never classify those points: the column leaves them out."""
    edge = X0 + 250.0
    xyz, hag, prob, n = faint_lattice(edge + 3.5, Y0 + 100)  # legs at most 3.2 m out: all east
    z = np.linspace(112.0, 120.0, 12)
    across = np.column_stack([np.full(12, edge - 0.3), Y0 + 100 + np.linspace(-1, 1, 12), z])
    xyz, hag = np.vstack([xyz, across]), np.r_[hag, z - 100.0].astype(np.float32)
    prob = np.r_[prob, np.full(12, 0.2, np.float32)]
    west = xyz[:, 0] < edge
    pairs = []
    for side, name in ((west, "bw"), (~west, "be")):
        arrays, meta = pred_pair(xyz[side], hag[side], prob[side], [name], tile=name)
        arrays["prob_single"] = prob[side].copy()
        pairs.append((arrays, meta))
    bw, be = (X0, Y0, edge, Y0 + 500), (edge, Y0, X0 + 500, Y0 + 500)
    east = extract(pairs, "be", be, zone="z1", column=COLUMN)
    assert len(east.towers) == 1 and east.towers.iloc[0]["blocks"] == "be"
    ((blocks, _),) = east.members.values()
    assert set(np.asarray(blocks).astype(str).tolist()) == {"be"}
    assert extract(pairs[::-1], "bw", bw, zone="z1", column=COLUMN).members == {}


def test_a_clustering_threshold_of_zero_gathers_every_point():
    xyz, hag, prob, n = faint_lattice(X0 + 50, Y0 + 50)
    arrays, meta = pred_pair(xyz, hag, prob, ["b1"])
    arrays["prob_single"] = prob.copy()
    off = {**COLUMN, "threshold": 0.0}
    # before the column, this setting gathered every point; it still does (the lattice and its crown),
    # where the configured threshold (0.0 is not "unset") leaves the lattice's faint points out
    every = extract([(arrays, meta)], "b1", BOUNDS, zone="z1", threshold=0.0, column=off)
    lattice = every.towers.sort_values("n_points").iloc[-1]
    assert lattice["n_points"] == n and every.towers["n_points"].sum() >= n + 0.9 * (len(xyz) - n)
    default = extract([(arrays, meta)], "b1", BOUNDS, zone="z1", threshold=0.5, column=off)
    assert default.towers["n_points"].max() < n


def test_the_shipped_column_leaves_the_foot_to_the_foot_rule():
    from conftest import tower_rules

    shipped = tower_rules().column
    xyz, hag, prob, n = faint_lattice(X0 + 50, Y0 + 50)
    arrays, meta = pred_pair(xyz, hag, prob, ["b1"])
    arrays["prob_single"] = prob.copy()
    found = extract([(arrays, meta)], "b1", BOUNDS, zone="z1", column=shipped)
    got = set(found.members[found.towers.iloc[0]["tower_id"]][1].tolist())
    faint = np.flatnonzero(prob[:n] < 0.5)
    high = faint[hag[faint] >= shipped["min_height"]]
    assert len(high) and set(high.tolist()) <= got  # the faint body above min_height is back
    assert not set(faint[hag[faint] < shipped["min_height"]].tolist()) & got  # the faint foot is not
