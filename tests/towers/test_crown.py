"""The crowns beside a tower (``towers.crowns``, :func:`towerpipe.towers.crown.crown_mask`)."""

from __future__ import annotations

import numpy as np

from conftest import tower_rules
from towerpipe.towers.crown import crown_mask

CROWNS = tower_rules().crowns  # the shipped rule


def lattice(height: float = 36.0, half_base: float = 3.5, half_top: float = 1.0, seed: int = 0):
    """Four legs narrowing upward, bracing on a face, and two crossarms near the top (10 m and
    6 m out on each side: the lower one wider): x, y, hag."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, height, 0.3)
    half = half_base + (half_top - half_base) * t / height
    parts = [np.stack([sx * half, sy * half, t], 1) for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1))]
    tb = rng.uniform(0, height, 200)
    hb = half_base + (half_top - half_base) * tb / height
    parts.append(np.stack([rng.uniform(-1, 1, 200) * hb, -hb, tb], 1))
    for z, reach in ((0.75 * height, 10.0), (0.9 * height, 6.0)):
        u = np.arange(-reach, reach, 0.25)
        parts.append(np.stack([u, np.zeros_like(u), np.full_like(u, z)], 1))
    xyz = np.concatenate(parts) + rng.normal(0, 0.05, (sum(len(p) for p in parts), 3))
    return xyz[:, 0], xyz[:, 1], np.maximum(xyz[:, 2], 0.0)


def crown(cx: float, cy: float, r: float = 3.0, top: float = 20.0, n: int = 400, seed: int = 1):
    """A tree's crown: a cap of radius ``r`` whose top is ``top`` m up."""
    rng = np.random.default_rng(seed)
    a, d = rng.uniform(0, 2 * np.pi, n), r * np.sqrt(rng.uniform(0, 1, n))
    return cx + d * np.cos(a), cy + d * np.sin(a), top - d - rng.uniform(0, 3, n)


def join(*parts):
    return tuple(np.concatenate(c) for c in zip(*parts, strict=True))


def test_the_crowns_beside_a_tower_go_and_the_tower_stays():
    tower = lattice()
    beside = crown(1.0, 8.0)  # 5 m beyond a face, 14-20 m up
    behind = crown(-1.0, -8.5, top=18.0, seed=2)  # beyond the opposite face
    under = crown(9.0, 0.0, r=1.5, top=20.0, seed=3)  # under the lower crossarm: within the outline above
    x, y, hag = join(tower, beside, behind, under)
    keep = crown_mask(x, y, hag, CROWNS)
    n, m = len(tower[0]), len(beside[0]) + len(behind[0])
    assert keep[:n].mean() > 0.99  # the legs, the faces and both crossarms
    assert keep[n : n + m].mean() < 0.05  # the crowns beside it
    assert keep[n + m :].all()  # what the crossarms overhang is left to the other rules
    assert keep[hag >= CROWNS["below"] * hag.max()].all()  # the upper part: never judged


def test_where_the_rule_cannot_judge_every_point_stays():
    tower, beside = lattice(), crown(1.0, 8.0)
    x, y, hag = join(tower, beside)
    assert crown_mask(x, y, hag, {**CROWNS, "beyond": 0.0}).all()  # switched off
    # a sparse tower (30 points): too few of them above the crowns to outline it
    n = len(tower[0])
    sparse = np.concatenate([np.arange(0, n, n // 30), np.arange(n, len(x))])
    assert (hag[sparse][:30] >= 11.0 + CROWNS["height"]).sum() < CROWNS["outline_points"]
    assert crown_mask(x[sparse], y[sparse], hag[sparse], CROWNS).all()
    nan = hag.copy()
    nan[::7] = np.nan  # points without a height stay, the others are judged
    keep = crown_mask(x, y, nan, CROWNS)
    assert keep[::7].all() and not keep.all()
    assert crown_mask(np.empty(0), np.empty(0), np.empty(0), CROWNS).shape == (0,)


def test_a_straight_pole_keeps_every_point():
    rng = np.random.default_rng(4)
    z = np.arange(0.0, 30.0, 0.1)
    x, y = rng.normal(0, 0.15, len(z)), rng.normal(0, 0.15, len(z))
    assert crown_mask(x, y, z, CROWNS).all()
