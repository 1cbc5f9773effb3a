"""A cluster's plan: a crane's jib against a tower's crossarms (rule 15, towers.max_arm_reach), and a piece
of conductor, over whose plan nothing stands (rule 16, towers.min_stand)."""

from __future__ import annotations

import numpy as np
import pytest
from test_shape import BASE_Z, _Scores
from test_towers import BOUNDS, X0, Y0, pred_pair, synthetic_tower

from conftest import extract
from towerpipe.towers.plan import JIB_MAX_WIDTH_M, arm_reach, base, tallest_stand


def crane(
    cx: float, cy: float, *, height: float = 35.0, jib: float = 30.0, counter: float = 10.0, heading: float = 0.3
):
    """Points of a tower crane: a 1.6 m lattice mast and, at its top, a 1.6 m wide jib reaching ``jib`` m
    one way and ``counter`` m the other along ``heading`` (rad); (xyz, hag)."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, height, 0.3)
    legs = [np.c_[np.full_like(t, sx * 0.8), np.full_like(t, sy * 0.8), t] for sx in (-1, 1) for sy in (-1, 1)]
    s = np.arange(-counter, jib, 0.3)
    chords = [np.c_[s, np.full_like(s, dy), np.full_like(s, height + dz)] for dy, dz in ((-0.8, 0), (0.8, 0), (0, 1.4))]
    local = np.concatenate(legs + chords)
    c, sn = np.cos(heading), np.sin(heading)
    xyz = np.c_[cx + c * local[:, 0] - sn * local[:, 1], cy + sn * local[:, 0] + c * local[:, 1], BASE_Z + local[:, 2]]
    xyz += rng.normal(0, 0.03, xyz.shape)
    return xyz, (xyz[:, 2] - BASE_Z).astype(np.float32)


def test_a_cluster_stands_on_its_lowest_third():
    """A crane's base is its mast, where the centroid of its points lies out along the jib; a
    tower's is the middle of its legs."""
    c_xyz, c_hag = crane(10.0, 20.0)
    np.testing.assert_allclose(base(c_xyz[:, :2], c_hag), [10.0, 20.0], atol=0.5)
    assert np.hypot(*(c_xyz[:, :2].mean(axis=0) - [10.0, 20.0])) > 3.0
    t_xyz, t_hag = synthetic_tower(0.0, 0.0, base_z=BASE_Z)
    np.testing.assert_allclose(base(t_xyz[:, :2], t_hag), [0.0, 0.0], atol=0.5)


def test_a_crane_reaches_far_and_narrow_a_tower_near_and_wide():
    c_xyz, c_hag = crane(0.0, 0.0)
    reach, width = arm_reach(c_xyz[:, :2], c_hag, (0.0, 0.0))
    assert 28.0 <= reach <= 30.0
    assert width <= JIB_MAX_WIDTH_M
    t_xyz, t_hag = synthetic_tower(0.0, 0.0, base_z=BASE_Z, arm=7.0)
    reach, width = arm_reach(t_xyz[:, :2], t_hag, (0.0, 0.0))
    assert 4.0 <= reach <= 7.5  # the crossarm: 7 m each side
    assert width > JIB_MAX_WIDTH_M  # the legs: 6 m apart at the base
    assert arm_reach(t_xyz[:2, :2], t_hag[:2], (0.0, 0.0)) == (0.0, 0.0)  # too few points to say


@pytest.mark.parametrize(("max_arm_reach", "kept"), [(0.0, 1), (13.0, 0), (35.0, 1)])
def test_rule_15_drops_a_crane_by_its_jib(max_arm_reach, kept):
    """A 35 m crane with 20 m of jib is dropped when its reach passes ``max_arm_reach``; a tower stays.
    (A cluster wider than 25 m is first split into its columns, each keeping 10 m of what hangs from
    it: the jib here fits in 25 m.)"""
    cx, cy = X0 + 250, Y0 + 250
    c_xyz, c_hag = crane(cx, cy, jib=20.0, counter=3.0)
    found = extract([pred_pair(c_xyz, c_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", max_arm_reach=max_arm_reach)
    assert len(found.towers) == kept
    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z)
    found = extract([pred_pair(t_xyz, t_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", max_arm_reach=max_arm_reach)
    assert len(found.towers) == 1


def test_rule_15_leaves_a_low_cluster_alone():
    """The rule judges clusters at least towers.wire_min_height high only (a 15 m crane is left to the others)."""
    c_xyz, c_hag = crane(X0 + 250, Y0 + 250, height=15.0)
    found = extract([pred_pair(c_xyz, c_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", max_arm_reach=13.0)
    assert len(found.towers) == 1


def test_the_rescue_does_not_find_a_dropped_crane_again(monkeypatch):
    """A crane rule 15 drops stays dropped: the rescue, clustering at its lower threshold, would join it
    to the faint crowns at its foot into a cluster too wide for the rule."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _Scores(1.0))
    rng = np.random.default_rng(6)
    cx, cy = X0 + 250, Y0 + 250
    c_xyz, c_hag = crane(cx, cy, jib=20.0, counter=3.0)
    r, a = 4.0 * np.sqrt(rng.random(600)), rng.uniform(0, 2 * np.pi, 600)
    crowns = np.c_[cx + r * np.cos(a), cy + r * np.sin(a), BASE_Z + rng.uniform(2.0, 10.0, 600)]
    xyz = np.r_[c_xyz, crowns]
    hag = (xyz[:, 2] - BASE_Z).astype(np.float32)
    prob = np.r_[np.full(len(c_xyz), 0.95), np.full(len(crowns), 0.2)].astype(np.float32)
    ctx = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": hag.astype(np.float64)}
    rules = {"max_arm_reach": 13.0, "rescue_threshold": 0.1, "min_shape_score": 0.5, "split_thresholds": []}
    trace: list = []
    found = extract(
        [pred_pair(xyz, hag, prob, ["b1"])],
        "b1",
        BOUNDS,
        zone="z1",
        context=lambda x, y: (ctx, (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)),
        trace=trace,
        **rules,
    )
    assert len(found.towers) == 0
    assert [t["rule"] for t in trace] == ["jib"]


def conductor_piece(cx: float, cy: float, *, span: float = 24.0, top: float = 15.0, sag: float = 6.0):
    """A painted piece of conductor: a catenary-like curve ``span`` m long, ``top`` m up at its ends and
    ``sag`` m lower in the middle, a point every 0.3 m; (xyz, hag)."""
    s = np.arange(-span / 2, span / 2, 0.3)
    hag = top - sag * (1 - (2 * s / span) ** 2)
    xyz = np.c_[cx + s, np.full_like(s, cy), BASE_Z + hag]
    return xyz, hag.astype(np.float32)


def test_nothing_stands_over_a_conductor_a_tower_stands():
    w_xyz, _ = conductor_piece(0.0, 0.0)
    assert tallest_stand(w_xyz) < 1.0  # over 1 m of its plan a sagging conductor drops 0.5 m at most
    t_xyz, _ = synthetic_tower(0.0, 0.0, base_z=BASE_Z)
    assert tallest_stand(t_xyz) > 10.0  # its legs, slanting 2 m over 30 m
    assert tallest_stand(np.empty((0, 3))) == 0.0


@pytest.mark.parametrize(("min_stand", "kept"), [(0.0, 1), (1.0, 0)])
def test_rule_16_drops_a_piece_of_conductor(min_stand, kept):
    """A painted piece of conductor that sags below ``max_base_ratio`` of its top (not floating) is
    dropped when nothing in it stands ``min_stand`` m over one spot; a tower stays."""
    cx, cy = X0 + 250, Y0 + 250
    w_xyz, w_hag = conductor_piece(cx, cy)
    found = extract([pred_pair(w_xyz, w_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", min_stand=min_stand)
    assert len(found.towers) == kept
    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z)
    found = extract([pred_pair(t_xyz, t_hag, 0.95, ["b1"])], "b1", BOUNDS, zone="z1", min_stand=min_stand)
    assert len(found.towers) == 1
