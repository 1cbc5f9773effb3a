"""What a cluster's conductors say about it: the sides of rule 14 (towers.min_conductor_balance), the
conductor's line of rule 17 (towers.max_line_share), a line over a crown (rule 20, towers.under_line) and a
crown in the canopy (rule 22, towers.canopy)."""

from __future__ import annotations

import numpy as np
import pytest
from test_plan import crane
from test_shape import BASE_Z, _Rejects, _Scores
from test_towers import BOUNDS, X0, Y0, pred_pair, synthetic_tower
from test_wires import conductor, spans

from conftest import extract
from towerpipe.towers.conductor_rules import (
    BALANCE_MIN_POINTS,
    CANOPY_RING_M,
    UNDER_LINE_GAP_M,
    canopy_clearance,
    conductor_balance,
    line_share,
    near_balance,
    under_line,
)

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


def detected(xyz: np.ndarray, direction=(1.0, 0.0)) -> dict[str, np.ndarray]:
    """Conductor points as the wire detector gives them (``arr["conductors"]``), their wire along ``direction``."""
    c = context(xyz)
    return {**c, "direction": np.tile(np.asarray(direction, np.float64), (len(xyz), 1))}


def test_a_piece_of_conductor_lies_on_its_line_a_tower_does_not():
    """The detector found a line but for 12 m of it: those 12 m lie on the lines of the conductors found
    either side; the tower the line hangs from holds them only at its crossarms' tips."""
    rng = np.random.default_rng(3)
    cx, cy = X0 + 250, Y0 + 250
    wires = line(cx, cy, 0.0, rng)
    gap = np.abs(wires[:, 0] - (cx - 60.0)) < 6.0
    found = context(wires[~gap])
    found["conductors"] = detected(wires[~gap])
    assert line_share(found, *wires[gap].T) > 0.95
    t_xyz, _ = synthetic_tower(cx, cy, base_z=BASE_Z)
    assert line_share(found, *t_xyz.T) < 0.2
    assert line_share(context(wires[~gap]), *wires[gap].T) == 0.0  # no conductor points: nothing to say
    across = detected(wires[~gap], direction=(0.0, 1.0))  # the same points, their wires crossing the piece
    assert line_share({"conductors": across}, *wires[gap].T) < 0.5


@pytest.mark.parametrize(("max_line_share", "kept"), [(1.0, 4), (0.9, 1)])
def test_rule_17_drops_a_piece_of_conductor_the_detector_left(max_line_share, kept):
    """A 14 m piece of a line (three conductors 5 m apart: three clusters) that the segmenter
    paints and the detector missed, the rest of the line found, is dropped when ``max_line_share`` is
    under 1; the tower on the same line stays."""
    rng = np.random.default_rng(4)
    cx, cy = X0 + 250, Y0 + 250
    wires = np.concatenate(
        [
            conductor(cx - 300, cy + dy, cx + 300, cy + dy, BASE_Z + 28.0, sag=8.0, step=0.35, rng=rng)
            for dy in (-5, 0, 5)
        ]
    )
    gap = np.abs(wires[:, 0] - (cx - 60.0)) < 7.0
    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z)
    ctx = context(t_xyz, wires)
    ctx["conductors"] = detected(wires[~gap])
    piece = wires[gap]
    preds = [pred_pair(np.r_[piece, t_xyz], np.r_[piece[:, 2] - BASE_Z, t_hag], 0.95, ["b1"])]
    rules = {"max_base_ratio": 1.0, "min_stand": 0.0, "max_arm_reach": 0.0, "max_line_share": max_line_share}
    rules["verifier"] = "none"
    found = extract(preds, "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, EXTENT), **rules)
    assert len(found.towers) == kept
    assert found.towers["height_m"].max() == pytest.approx(30.0, abs=1.0)  # the tower is always there


class _TallObjects:
    """A verifier that takes an object reaching 18 m for a tower (conductors over a crown make one)."""

    def score(self, x, y, hag):
        return 0.99 if np.max(hag) >= 18.0 else 0.0


@pytest.mark.parametrize(("min_bare_score", "kept"), [(0.0, 2), (0.5, 1)])
def test_rule_18_drops_a_crown_that_its_conductors_make_a_tower(monkeypatch, min_bare_score, kept):
    """A 16 m crown under a line whose conductors pass 20 m up: its object, the conductors over it
    included, passes the shape check; without them it is a crown, dropped when ``min_bare_score`` is on.
    The tower on the same line keeps its score."""
    import towerpipe.towers.extract as ex

    monkeypatch.setattr(ex, "load_verifier", lambda spec: _TallObjects())
    rng = np.random.default_rng(5)
    cx, cy = X0 + 250, Y0 + 250
    wires = np.concatenate(
        [
            conductor(cx - 300, cy + dy, cx + 300, cy + dy, BASE_Z + 28.0, sag=8.0, step=0.35, rng=rng)
            for dy in (-5, 0, 5)
        ]
    )
    u = rng.normal(size=(400, 3))
    crown = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.random((400, 1)) ** (1 / 3) * [3.0, 3.0, 4.0]
    crown += [cx - 60.0, cy + 2.0, BASE_Z + 12.0]
    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z)
    ctx = context(t_xyz, crown, wires)
    ctx["conductors"] = detected(wires)
    preds = [pred_pair(np.r_[crown, t_xyz], np.r_[crown[:, 2] - BASE_Z, t_hag], 0.95, ["b1"])]
    rules = {"max_base_ratio": 1.0, "min_stand": 0.0, "max_arm_reach": 0.0, "min_bare_score": min_bare_score}
    rules["under_line"] = 0  # rule 20 drops this crown too (the line 4 m over it): rule 18 alone here
    trace = []
    found = extract(preds, "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, EXTENT), trace=trace, **rules)
    assert len(found.towers) == kept
    assert found.towers["height_m"].max() == pytest.approx(30.0, abs=1.0)
    assert ("bare" in {t["rule"] for t in trace}) == (kept == 1)  # the crown, and its split parts


def test_near_conductors_a_tower_between_them_a_crane_beside_them_or_by_a_passing_line():
    """Rule 19's balance of the conductors within 80 m: about 2/3 for a base under a line (a third each
    side, a third over), near 0 beside it (the nearest conductor 7 m away), 0 where the line passes 30 m
    away (none of its wires points at the base), unknown with no conductor near."""
    rng = np.random.default_rng(5)
    cx, cy = X0 + 250, Y0 + 250
    assert near_balance(context(line(cx, cy, 0.0, rng)), cx, cy) == pytest.approx(2 / 3, abs=0.1)
    assert near_balance(context(line(cx, cy, 12.0, rng)), cx, cy) < 0.05
    assert near_balance(context(line(cx, cy, 30.0, rng)), cx, cy) == 0.0
    assert np.isnan(near_balance(context(line(cx, cy, 120.0, rng)), cx, cy))
    # the detector's conductor points, when the context has them, are the ones read
    wires = line(cx, cy, 30.0, rng)
    assert near_balance({"conductors": detected(wires)}, cx, cy) == 0.0


@pytest.mark.parametrize(("min_near_balance", "heights"), [(0.09, [30.0]), (0.0, [30.0, 36.0])])
def test_rule_19_drops_a_crane_beside_a_line_on_a_tile_too_small_for_the_ring(min_near_balance, heights):
    """On a 100 m tile no 80-160 m ring lies in the data: the support is unknown and rule 8 judges
    nothing. The conductors within 80 m stand in: a crane 14 m beside the line has them all on one side
    and is dropped; the tower the line hangs from is kept."""
    rng = np.random.default_rng(6)
    cx, cy = X0 + 250, Y0 + 250
    c_xyz, c_hag = crane(cx, cy - 14.0, jib=8.0, heading=np.pi / 2)
    t_xyz, t_hag = synthetic_tower(cx + 20.0, cy, base_z=BASE_Z)
    wires = line(cx, cy, 0.0, rng)
    wires = wires[np.abs(wires[:, 0] - cx) < 50.0]
    ctx = context(c_xyz, t_xyz, wires)
    small = (cx - 50.0, cy - 50.0, cx + 50.0, cy + 50.0)
    rules = {"min_wire_support": 0.5, "max_arm_reach": 0.0, "min_near_balance": min_near_balance}
    preds = [pred_pair(np.r_[c_xyz, t_xyz], np.r_[c_hag, t_hag], 0.95, ["b1"])]
    found = extract(preds, "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, small), verifier="none", **rules)
    assert sorted(found.towers["height_m"].round().tolist()) == heights
    assert found.towers["wire_support"].isna().all()


@pytest.mark.parametrize(("min_near_balance", "kept"), [(0.09, 1), (0.0, 0)])
def test_rule_19_keeps_a_tower_whose_far_conductors_were_not_found(min_near_balance, kept):
    """A 30 m tower whose conductors the detector found only within 60 m of it (a sparse flight: the
    80-160 m ring, in the data, holds none): its support is 0 and rule 8 drops it, but the conductors
    near it hang on both sides of it and over it, so rule 19 keeps it."""
    rng = np.random.default_rng(7)
    cx, cy = X0 + 250, Y0 + 250
    t_xyz, t_hag = synthetic_tower(cx, cy, base_z=BASE_Z)
    wires = line(cx, cy, 0.0, rng)
    ctx = context(t_xyz, wires[np.abs(wires[:, 0] - cx) < 60.0])
    rules = {"min_wire_support": 0.5, "min_near_balance": min_near_balance}
    preds = [pred_pair(t_xyz, t_hag, 0.95, ["b1"])]
    found = extract(preds, "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, EXTENT), verifier="none", **rules)
    assert len(found.towers) == kept
    if kept:
        assert found.towers["wire_support"].iloc[0] == 0.0  # recorded as measured


def _three_wires(x0: float, x1: float, y: float, z: float, sag: float, rng: np.random.Generator) -> np.ndarray:
    """Three conductors 5 m apart along x from ``x0`` to ``x1``, hung at elevation ``z``, sagging ``sag``."""
    return np.concatenate(
        [conductor(x0, y + dy, x1, y + dy, z, sag=sag, step=0.35, rng=rng) for dy in (-5.0, 0.0, 5.0)]
    )


def test_a_tower_holds_its_conductors_a_crown_under_a_line_has_them_over_it():
    """Rule 20's counts: the conductors within 25 m pointing at a base, over the top of its object by
    more than 2 m or not. A tower hangs its own at or below its top, also when the segmenter painted
    only its lower half (the object's points above carry the top up); a crown under a line has the
    line over it only, clear of it (the conductor points over its footprint are not its top); a line
    passing by points at neither."""
    rng = np.random.default_rng(8)
    cx, cy = X0 + 250, Y0 + 250
    wires = _three_wires(cx - 300, cx + 300, cy, BASE_Z + 28.0, 8.0, rng)
    t_xyz, _ = synthetic_tower(cx - 300.0, cy, base_z=BASE_Z)
    u = rng.normal(size=(300, 3))
    crown = u / np.linalg.norm(u, axis=1, keepdims=True) * [3.0, 3.0, 2.0] + [cx - 60.0, cy, BASE_Z + 12.0]
    ctx = context(t_xyz, crown, wires)
    ctx["conductors"] = detected(wires)
    n_t, n_c = len(t_xyz), len(crown)
    tower, crown_obj = np.arange(n_t), n_t + np.arange(n_c)
    over_crown = n_t + n_c + np.flatnonzero(np.hypot(wires[:, 0] - (cx - 60.0), wires[:, 1] - cy) < 4.0)
    c_top = float(crown[:, 2].max())
    over, under = under_line(ctx, cx - 60.0, cy, c_top, np.r_[crown_obj, over_crown])
    assert over > 50 and under == 0
    over, under = under_line(ctx, cx - 300.0, cy, float(t_xyz[:, 2].max()), tower)
    assert over == 0 and under > 50
    half = float(np.quantile(t_xyz[:, 2], 0.5))  # what a segmenter painted, the lower half: the object carries it up
    assert under_line(ctx, cx - 300.0, cy, half, tower) == (over, under)
    assert under_line(ctx, cx - 300.0, cy, half, tower[:0])[0] > 50  # without its object it would not
    assert under_line(ctx, cx - 60.0, cy + 40.0, c_top, crown_obj) == (0, 0)  # a line passing by
    assert UNDER_LINE_GAP_M < float(wires[np.hypot(wires[:, 0] - (cx - 60.0), wires[:, 1] - cy) < 4.0, 2].min()) - c_top


@pytest.mark.parametrize(("under_line_points", "heights"), [(0, [14.0, 20.0, 30.0, 30.0]), (5, [20.0, 30.0, 30.0])])
def test_rule_20_drops_a_crown_under_a_line_not_a_tower_under_a_crossing_line(under_line_points, heights):
    """A 14 m crown under a line strung between two 30 m towers passes every other rule (the shape check
    off, conductors pointing at it from both sides); rule 20 drops it. A 20 m tower of a lower line,
    another line crossing 20 m over it, holds its own conductors and stays."""
    rng = np.random.default_rng(9)
    cx, cy = X0 + 250, Y0 + 250
    a, b = cx - 150.0, cx + 150.0  # the line's towers, 300 m apart
    t1, h1 = synthetic_tower(a, cy, base_z=BASE_Z)
    t2, h2 = synthetic_tower(b, cy, base_z=BASE_Z, seed=1)
    t3, h3 = synthetic_tower(cx, cy + 120.0, height=20.0, base_z=BASE_Z, seed=2)
    along = np.concatenate(
        [
            _three_wires(a - 300, a, cy, BASE_Z + 28.0, 8.0, rng),
            _three_wires(a, b, cy, BASE_Z + 28.0, 8.0, rng),
            _three_wires(b, b + 300, cy, BASE_Z + 28.0, 8.0, rng),
            _three_wires(cx - 250, cx, cy + 120.0, BASE_Z + 18.0, 5.0, rng),  # the lower line, from the 20 m tower
            _three_wires(cx, cx + 250, cy + 120.0, BASE_Z + 18.0, 5.0, rng),
        ]
    )
    crossing = np.concatenate(
        [
            conductor(cx + dx, cy + 20.0, cx + dx, cy + 420.0, BASE_Z + 42.0, sag=4.0, step=0.35, rng=rng)
            for dx in (-5, 0, 5)
        ]
    )
    u = rng.normal(size=(400, 3))
    crown = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.random((400, 1)) ** (1 / 3) * [3.0, 3.0, 2.0]
    crown += [cx + 40.0, cy, BASE_Z + 12.0]
    crown[:, 2] = np.minimum(crown[:, 2], BASE_Z + 14.0)
    ctx = context(t1, t2, t3, crown, along, crossing)
    by_x, by_y = detected(along), detected(crossing, direction=(0.0, 1.0))
    ctx["conductors"] = {k: np.concatenate([by_x[k], by_y[k]]) for k in by_x}
    t3_obj = len(t1) + len(t2) + np.arange(len(t3))
    assert (
        under_line(ctx, cx, cy + 120.0, float(t3[:, 2].max()), t3_obj)[0] >= 5
    )  # the line crossing over the 20 m tower
    xyz = np.r_[t1, t2, t3, crown]
    preds = [pred_pair(xyz, np.r_[h1, h2, h3, crown[:, 2] - BASE_Z], 0.95, ["b1"])]
    rules = {"max_base_ratio": 1.0, "min_stand": 0.0, "max_arm_reach": 0.0, "under_line": under_line_points}
    trace = []
    found = extract(
        preds, "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, EXTENT), verifier="none", trace=trace, **rules
    )
    assert sorted(found.towers["height_m"].round().tolist()) == heights
    assert ("under" in {t["rule"] for t in trace}) == (under_line_points > 0)


def _wood(cx: float, cy: float, rng: np.random.Generator, top: float = 14.0, radius: float = 60.0) -> np.ndarray:
    """A wood around ``(cx, cy)``: crowns' points 8 m up to about ``top`` m, 2 a square metre."""
    n = int(2.0 * np.pi * radius**2)
    r, a = radius * np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)
    h = top - 6.0 * rng.random(n) ** 2  # most points near the canopy's top
    return np.c_[cx + r * np.cos(a), cy + r * np.sin(a), BASE_Z + h]


def _crown(cx: float, cy: float, top: float, rng: np.random.Generator) -> np.ndarray:
    u = rng.normal(size=(300, 3))
    crown = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.random((300, 1)) ** (1 / 3) * [3.0, 3.0, 3.0]
    return crown + [cx, cy, BASE_Z + top - 3.0]


def test_the_canopy_around_a_base_is_its_ring_s_90th_percentile():
    rng = np.random.default_rng(10)
    cx, cy = X0 + 250, Y0 + 250
    wood = _wood(cx, cy, rng)
    ctx = context(wood)
    d = np.hypot(wood[:, 0] - cx, wood[:, 1] - cy)
    ring = (d >= CANOPY_RING_M[0]) & (d < CANOPY_RING_M[1])
    assert canopy_clearance(ctx, cx, cy, 20.0) == pytest.approx(20.0 - np.percentile(ctx["hag"][ring], 90))
    assert 5.5 < canopy_clearance(ctx, cx, cy, 20.0) < 6.5  # a 20 m tower over a wood of 14 m
    assert np.isnan(canopy_clearance(ctx, cx + 500.0, cy, 20.0))  # nothing around: nothing to compare with


@pytest.mark.parametrize(("conductors", "heights"), [(0, [14.0, 14.0, 20.0]), (12, [14.0, 20.0])])
def test_rule_22_drops_a_crown_in_the_wood_not_a_tower_over_it_nor_one_holding_conductors(conductors, heights):
    """Three clusters pass every other rule (the shape check off) in a wood of 14 m: a 14 m crown, a 20 m
    tower standing over the wood, both with no conductor near them, and a 14 m tower in the wood whose
    line's conductors hang from it. Rule 22 drops the crown alone: nothing hangs from it and it does not
    rise over the wood."""
    rng = np.random.default_rng(11)
    cx, cy = X0 + 250, Y0 + 250
    crown = _crown(cx, cy, 14.0, rng)
    t1, h1 = synthetic_tower(cx + 120.0, cy, height=20.0, base_z=BASE_Z)
    t2, h2 = synthetic_tower(cx, cy + 150.0, height=14.0, arm=4.0, base_z=BASE_Z, seed=1)
    wires = _three_wires(cx - 300, cx + 300, cy + 150.0, BASE_Z + 13.0, 3.0, rng)
    wood = np.concatenate([_wood(x, y, rng) for x, y in ((cx, cy), (cx + 120.0, cy), (cx, cy + 150.0))])
    ctx = context(crown, t1, t2, wood, wires)
    ctx["conductors"] = detected(wires)
    xyz = np.r_[crown, t1, t2]
    preds = [pred_pair(xyz, np.r_[crown[:, 2] - BASE_Z, h1, h2], 0.95, ["b1"])]
    canopy = {"conductors": conductors, "clearance": 3.0, "max_height": 25.0}
    rules = {"max_base_ratio": 1.0, "min_stand": 0.0, "max_arm_reach": 0.0, "under_line": 5, "canopy": canopy}
    trace = []
    found = extract(
        preds, "b1", BOUNDS, zone="z1", context=lambda x, y: (ctx, EXTENT), verifier="none", trace=trace, **rules
    )
    assert sorted(found.towers["height_m"].round().tolist()) == heights
    assert ("canopy" in {t["rule"] for t in trace}) == (conductors > 0)
