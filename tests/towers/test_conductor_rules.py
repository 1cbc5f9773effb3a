"""What a cluster's conductors say about it: the sides of rule 14 (towers.min_conductor_balance)."""

from __future__ import annotations

import numpy as np
import pytest
from test_plan import crane
from test_shape import BASE_Z, _Rejects, _Scores
from test_towers import BOUNDS, X0, Y0, pred_pair, synthetic_tower
from test_wires import conductor, spans

from conftest import extract
from towerpipe.towers.conductor_rules import BALANCE_MIN_POINTS, conductor_balance

EXTENT = (X0 - 200, Y0 - 200, X0 + 700, Y0 + 700)


def line(cx: float, cy: float, across: float, rng: np.random.Generator) -> np.ndarray:
    """Three conductors at 5 m apart, 28 m up, along x through (cx, cy + across), 300 m each way."""
    parts = [
        conductor(cx - 300.0, cy + across + dy, cx + 300.0, cy + across + dy, BASE_Z + 28.0, sag=8.0, rng=rng)
        for dy in (-5.0, 0.0, 5.0)
    ]
    return np.concatenate(parts)


def context(*clouds: np.ndarray) -> dict[str, np.ndarray]:
    xyz = np.concatenate(clouds)
    return {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "hag": xyz[:, 2] - BASE_Z}


def test_a_tower_stands_between_its_conductors_a_crane_beside_them():
    rng = np.random.default_rng(0)
    cx, cy = X0 + 250, Y0 + 250
    through = context(line(cx, cy, 0.0, rng))
    assert conductor_balance(through, cx, cy) == pytest.approx(2 / 3, abs=0.1)  # a third each side, a third over
    beside = context(line(cx, cy, 12.0, rng))  # the nearest conductor 7 m away, all on one side
    assert conductor_balance(beside, cx, cy) < 0.05
    # flipping every wire's direction changes nothing: a wire's sign is arbitrary
    c = {**beside, "conductors": {**beside, "direction": np.tile([[-1.0, 0.0]], (len(beside["x"]), 1))}}
    c["conductors"]["direction"][::2] *= -1
    assert conductor_balance(c, cx, cy) == conductor_balance(beside, cx, cy)


def test_the_balance_is_unknown_with_few_conductor_points():
    rng = np.random.default_rng(1)
    cx, cy = X0 + 250, Y0 + 250
    pts = line(cx, cy, 0.0, rng)
    ring = np.abs(pts[:, 0] - cx) >= 80.0
    few = np.concatenate([pts[~ring], pts[ring][: BALANCE_MIN_POINTS - 5]])
    assert np.isnan(conductor_balance(context(few), cx, cy))


@pytest.mark.parametrize(
    ("balance", "shape", "kept"),
    [(0.0, None, 1), (0.1, None, 0), (0.1, 0.9, 0), (0.1, 1.0, 1)],
)
def test_rule_14_drops_a_crane_beside_a_line(monkeypatch, balance, shape, kept):
    """A 35 m crane 10 m beside a line (its nearest conductor 5 m away: a support of 1) is dropped when
    ``min_conductor_balance`` is on and its shape is in doubt (no verifier, or a score under
    ``min_shape_score`` that rule 13 lets pass); a shape the verifier is sure of is not asked. A tower on
    the same line is kept."""
    import towerpipe.towers.extract as ex

    if shape is not None:
        monkeypatch.setattr(ex, "load_verifier", lambda spec: _Scores(shape))
    rng = np.random.default_rng(2)
    cx, cy = X0 + 250, Y0 + 250
    c_xyz, c_hag = crane(cx, cy - 10.0, jib=8.0, heading=np.pi / 2)
    t_xyz, t_hag = synthetic_tower(cx + 150.0, cy, base_z=BASE_Z)
    ctx = context(c_xyz, t_xyz, line(cx, cy, 0.0, rng))
    rules = {
        "min_wire_support": 0.5,
        "min_conductor_balance": balance,
        "max_arm_reach": 0.0,
        "min_shape_score": 0.95,
        "tall_shape_score": 0.85,
        "split_thresholds": [],
        "rescue_threshold": 0.0,
    }
    preds = [pred_pair(np.r_[c_xyz, t_xyz], np.r_[c_hag, t_hag], 0.95, ["b1"])]
    verifier = "none" if shape is None else "shipped"
    found = extract(preds, "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, EXTENT), verifier=verifier, **rules)
    heights = sorted(found.towers["height_m"].round().tolist())
    assert heights == ([30.0, 36.0] if kept else [30.0])  # the tower, and the crane with its jib
    assert (found.towers["wire_support"] == 1.0).all()


@pytest.mark.parametrize(("balance", "rule", "kept"), [(np.nan, 0.125, 0), (np.nan, 0.0, 1), (0.4, 0.125, 1)])
def test_a_vouch_needs_the_conductors_sides_known(monkeypatch, balance, rule, kept):
    """A 30 m tower the verifier takes for a tree, with conductors at 28 m: rule 12 vouches for it. With
    rule 14 on, an unknown balance (too few conductor points to say where they lie) drops it; a known
    balance over the threshold keeps it, and so does the rule off."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _Rejects())
    monkeypatch.setattr(ex, "conductor_balance", lambda arr, bx, by: balance)
    rng = np.random.default_rng(2)
    cx, cy = X0 + 250, Y0 + 250
    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z, seed=3)
    ctx = context(t_xyz, spans(cx, cy, BASE_Z + 28.0, rng))
    rules = {"min_shape_score": 0.5, "split_thresholds": [], "vouch_height": 5.0, "min_conductor_balance": rule}
    pair = pred_pair(t_xyz, t_hag, 0.95, ["b1"])
    found = extract([pair], "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, EXTENT), **rules)
    assert len(found.towers) == kept
    if kept:
        assert found.towers["shape_score"].iloc[0] == 0.0  # kept against the shape check: rule 12's
