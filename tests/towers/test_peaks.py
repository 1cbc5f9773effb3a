"""Two towers under one cluster's tops (towerpipe.towers.peaks, rule 23): parted at their peaks
when a crown links their bodies, while one tower (its earth-wire peaks, a shrub at its foot) stays
one; and the rule in :func:`towerpipe.towers.extract.extract_towers`."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import TOWERS, extract, tower_returns
from towerpipe.synth.towers import DESIGNS, HEIGHTS, UTILITY
from towerpipe.towers.cluster import cluster_towers
from towerpipe.towers.peaks import peak_parts

LINKAGE = 2.5
PROMINENCE = 2.0
SHARE = 0.25


def _crown(x, radius, bottom, top, n=600, seed=0):
    """The points of a crown (an ellipsoid's surface, ``bottom`` to ``top`` m high) centred at (x, 0)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    mid, half = (bottom + top) / 2, (top - bottom) / 2
    xyz = np.c_[x + radius * u[:, 0], radius * u[:, 1], mid + half * u[:, 2]]
    return xyz, xyz[:, 2].copy()


def _parts(xyz, hag, share=SHARE, min_points=20):
    return peak_parts(xyz, hag, linkage=LINKAGE, prominence=PROMINENCE, share=share, min_points=min_points)


def _linked_pair(gap=18.0):
    """A tonne and a double-circuit tower ``gap`` m apart with a crown between them linking their
    bodies: (xyz, hag, which tower each point is, -1 for the crown)."""
    a, ha = tower_returns("tonne", 0.0, 1.57, 1, height=50.0)
    b, hb = tower_returns("double_circuit", gap, 1.57, 2, height=32.0)
    c, hc = _crown(gap / 2, gap / 2 - 1.0, 6.0, 18.0, seed=3)
    own = np.r_[np.zeros(len(a), int), np.ones(len(b), int), np.full(len(c), -1)]
    return np.r_[a, b, c], np.r_[ha, hb, hc], own


@pytest.mark.parametrize("density", [2.0, 4.0, 10.0])
@pytest.mark.parametrize("design", DESIGNS + UTILITY)
def test_one_tower_is_never_parted(design, density):
    """Every design at its lowest and highest, its earth-wire peaks, a portal's beam and an H-frame's
    poles included, stays one, on flights of 2 to 10 pts/m² (at 2, its crossarms' cells half empty)."""
    for seed in (1, 2, 3, 4):
        for height in HEIGHTS[design]:
            xyz, hag = tower_returns(design, 0.0, 0.3 * seed, seed, height=height, density=density)
            assert (_parts(xyz, hag) == 0).all(), (design, density, seed, height)


@pytest.mark.shared
def test_no_real_tower_is_parted():
    """Every real tower shape of ../shared (UAV lattices, TS40K towers, utility structures: two
    poles of an H-frame standing 3.5 m over its beam among them), thinned to 2-15 pts/m², stays
    one. A share of 0.10 parts four towers of these two tests: a waisted lattice at 2, 4 and
    10 pts/m², a UAV lattice at 4."""
    from towerpipe.synth.real import airborne_resample, load_real_towers

    for name, shape in load_real_towers(TOWERS):
        for density in (2.0, 4.0, 8.0, 15.0):
            xyz = airborne_resample(shape, density, np.random.default_rng(int(density)))
            if len(xyz) >= 40:
                assert (_parts(xyz, xyz[:, 2].copy()) == 0).all(), (name, density)


def test_two_towers_linked_by_a_crown_are_parted():
    """The crown links the towers' bodies, so they are one cluster and stand on one mast; their
    tops part them, each tower's points going to one part."""
    xyz, hag, own = _linked_pair()
    assert (
        cluster_towers(xyz, hag, linkage=LINKAGE, mast_prominence=PROMINENCE, min_points=20, min_height=9.0).max() == 0
    )
    labels = _parts(xyz, hag)
    assert labels.max() == 1
    first = np.bincount(labels[own == 0], minlength=2).argmax()
    assert np.mean(labels[own == 0] == first) > 0.95
    assert np.mean(labels[own == 1] == 1 - first) > 0.95


def test_share_zero_never_parts():
    xyz, hag, _ = _linked_pair()
    assert (_parts(xyz, hag, share=0.0) == 0).all()


def test_a_low_peak_beside_a_tower_is_no_tower():
    """A crown or a shrub beside a tower's foot, under LOW_SHARE of its height, is no tower of its own."""
    a, ha = tower_returns("delta", 0.0, 0.0, 1, height=40.0)
    c, hc = _crown(9.0, 4.0, 3.0, 14.0, seed=4)
    assert (_parts(np.r_[a, c], np.r_[ha, hc]) == 0).all()


def test_every_part_needs_mintower_returns():
    """Parts of fewer than ``min_points`` points are no towers: the cluster stays whole."""
    xyz, hag, own = _linked_pair()
    assert (_parts(xyz, hag, min_points=int((own == 1).sum()) * 3) == 0).all()


def test_rule_23_reports_two_towers_where_there_were_one():
    """In the tower rules, the accepted cluster is parted and each part judged and reported; with
    ``peak_share`` 0 it is one tower whose outline spans both."""
    xyz, hag, _ = _linked_pair()
    n = len(xyz)
    arrays = {"block_id": np.zeros(n, np.int32), "point_index": np.arange(n), "hag": hag.astype(np.float32)}
    arrays.update(zip("xyz", (xyz + [400_100.0, 4_600_100.0, 100.0]).T))
    arrays["prob"] = np.full(n, 0.9, np.float32)
    meta = {"zone": "z", "block": "b", "tile": "t", "blocks": ["b"], "crs_wkt": "EPSG:25831", "core_bounds": [0] * 4}
    bounds = (400_000.0, 4_600_000.0, 400_500.0, 4_600_500.0)
    two = extract([(arrays, meta)], "b", bounds, zone="z", peak_share=SHARE).towers
    one = extract([(arrays, meta)], "b", bounds, zone="z", peak_share=0.0).towers
    assert len(one) == 1 and len(two) == 2
    two = two.sort_values("centroid_x")
    np.testing.assert_allclose(two["height_m"], [50.0, 32.0], atol=1.0)
    # each within the 5 m a match allows of where its tower stands (the crown between them shared
    # out), the one tower in between
    np.testing.assert_allclose(two["centroid_x"], [400_100.0, 400_118.0], atol=5.0)
    assert 400_103.0 < one["centroid_x"].iloc[0] < 400_115.0
