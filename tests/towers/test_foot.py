"""Tests of towerpipe.towers.foot: which points of a tower's foot are reported."""

from __future__ import annotations

import numpy as np

from conftest import tower_rules
from towerpipe.towers.foot import foot_mask

FOOT = tower_rules().foot  # the shipped rule


def lattice(height: float = 30.0, half_base: float = 3.0, half_top: float = 1.0, step: float = 0.3, seed: int = 0):
    """Four legs splaying to the ground and bracing on the faces: x, y, hag."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, height, step)
    half = half_base + (half_top - half_base) * t / height
    parts = [np.stack([sx * half, sy * half, t], 1) for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1))]
    # a face's diagonal bracing: along the outline between two legs
    u = rng.uniform(-1, 1, 200)
    tb = rng.uniform(0, height, 200)
    hb = half_base + (half_top - half_base) * tb / height
    parts.append(np.stack([u * hb, -hb, tb], 1))
    xyz = np.concatenate(parts) + rng.normal(0, 0.05, (sum(len(p) for p in parts), 3))
    return xyz[:, 0], xyz[:, 1], np.maximum(xyz[:, 2], 0.0)


def shrubs(cx: float, cy: float, r: float, n: int = 150, top: float = 4.0, seed: int = 1):
    rng = np.random.default_rng(seed)
    a, d = rng.uniform(0, 2 * np.pi, n), r * np.sqrt(rng.uniform(0, 1, n))
    return cx + d * np.cos(a), cy + d * np.sin(a), rng.uniform(0.3, top, n)


def join(*parts):
    return tuple(np.concatenate(c) for c in zip(*parts, strict=True))


def test_the_legs_stay_and_the_shrubs_between_and_beside_them_go():
    tower = lattice()
    inside = shrubs(0.0, 0.0, 1.5)  # between the legs (3 m out at the ground)
    beside = shrubs(7.0, 0.0, 1.5, seed=2)  # beyond a face
    x, y, hag = join(tower, inside, beside)
    keep = foot_mask(x, y, hag, FOOT)
    n = len(tower[0])
    assert keep[:n].mean() > 0.98  # the splaying legs and the bracing
    assert keep[n:].mean() < 0.05  # the vegetation
    assert keep[hag >= FOOT["height"]].all()  # above the foot: untouched


def test_a_pole_keeps_its_shaft_not_the_bush_beside_it():
    rng = np.random.default_rng(3)
    z = np.arange(0.0, 14.0, 0.2)
    pole = (rng.normal(0, 0.1, len(z)), rng.normal(0, 0.1, len(z)), z)
    bush = shrubs(2.5, 0.0, 0.8, seed=4)
    x, y, hag = join(pole, bush)
    keep = foot_mask(x, y, hag, FOOT)
    assert keep[: len(z)].all()
    assert not keep[len(z) :].any()


def test_where_the_rule_cannot_judge_every_point_stays():
    x, y, hag = join(lattice(), shrubs(0.0, 0.0, 1.5))
    assert foot_mask(x, y, hag, {**FOOT, "height": 0.0}).all()  # switched off
    low = hag < 7.0  # a tower lower than the foot's height: no outline above
    assert foot_mask(x[low], y[low], hag[low], FOOT).all()
    z = np.arange(0.0, 14.0, 0.2)  # the points above all on one line
    assert foot_mask(np.zeros_like(z), z * 0.1, z, FOOT).all()
    # a sparse tower: too few points between 8 and 14 m to outline it
    sparse = (hag >= FOOT["height"]) & (hag < FOOT["height"] + FOOT["band"])
    sparse = np.flatnonzero(sparse)[:: max(1, int(sparse.sum()) // (FOOT["outline_points"] - 1))]
    sel = np.concatenate([np.flatnonzero(hag < FOOT["height"]), sparse])
    assert len(sparse) < FOOT["outline_points"]
    assert foot_mask(x[sel], y[sel], hag[sel], FOOT).all()
    assert foot_mask(np.empty(0), np.empty(0), np.empty(0), FOOT).shape == (0,)
