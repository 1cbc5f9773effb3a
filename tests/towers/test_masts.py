"""Two towers in one cluster (towerpipe.towers.masts): split by their masts, while one tower on
two masts (a portal, an H-frame) stays one."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import tower_returns
from towerpipe.synth.towers import DESIGNS, HEIGHTS, UTILITY
from towerpipe.towers.cluster import cluster_towers
from towerpipe.towers.masts import mast_bodies, split_masts

LINKAGE = 2.5
PROMINENCE = 2.0


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("design", DESIGNS + UTILITY)
def test_one_tower_is_never_split(design, seed):
    """Every design, a portal's two columns and an H-frame's two poles included, stays one tower."""
    xyz, hag = tower_returns(design, 0.0, 0.4 * seed, seed)
    assert (split_masts(xyz, hag, linkage=LINKAGE, prominence=PROMINENCE) == 0).all()


@pytest.mark.parametrize(
    ("design", "gap", "rot"),
    [("double_circuit", 10.0, 1.57), ("donau", 12.0, 0.8), ("einebenen", 16.0, 0.0), ("tonne", 14.0, 0.0)],
)
def test_two_towers_whose_crossarms_link_are_split(design, gap, rot):
    """Two towers of a double line or of two lines crossing, a smaller one beside a larger one, their
    crossarms linked: one cluster without the split, one tower each with it."""
    a, ha = tower_returns(design, 0.0, rot, 1)
    b, hb = tower_returns(design, gap, rot, 2, height=HEIGHTS[design][0] + 2.0)
    xyz, hag = np.r_[a, b], np.r_[ha, hb]
    whole = cluster_towers(xyz, hag, linkage=LINKAGE, min_points=20, min_height=9.0)
    assert whole.max() == 0, "the two towers must make one cluster for the split to matter"
    labels = split_masts(xyz, hag, linkage=LINKAGE, prominence=PROMINENCE, min_points=20)
    assert labels.max() == 1
    own = np.r_[np.zeros(len(a), int), np.ones(len(b), int)]
    # each tower's points go to one label, the other tower's to the other
    first = np.bincount(labels[own == 0], minlength=2).argmax()
    assert np.mean(labels[own == 0] == first) > 0.98
    assert np.mean(labels[own == 1] == 1 - first) > 0.98
    split = cluster_towers(xyz, hag, linkage=LINKAGE, mast_prominence=PROMINENCE, min_points=20, min_height=9.0)
    assert split.max() == 1


@pytest.mark.parametrize("rot", [0.0, 0.8])
@pytest.mark.parametrize("gap", [10.0, 14.0])
def test_a_portal_beside_a_tower_keeps_its_beam(gap, rot):
    """A portal's two columns are never cut apart, whatever stands beside it."""
    p, hp = tower_returns("portal", 0.0, rot, 4)
    t, ht = tower_returns("delta", gap, rot, 5)
    labels = split_masts(np.r_[p, t], np.r_[hp, ht], linkage=LINKAGE, prominence=PROMINENCE, min_points=20)
    assert len(np.unique(labels[: len(p)])) == 1


def test_a_split_needs_towers_standing_on_the_ground():
    """A part that does not reach the ground (a crown painted with a tower, a piece of crossarm)
    or holds fewer than ``min_points`` points is no tower: the cluster stays whole."""
    a, ha = tower_returns("donau", 0.0, 0.8, 1)
    b, hb = tower_returns("donau", 12.0, 0.8, 2, height=HEIGHTS["donau"][0] + 2.0)
    xyz, hag = np.r_[a, b], np.r_[ha, hb]
    assert split_masts(xyz, hag, linkage=LINKAGE, prominence=PROMINENCE, min_points=20).max() == 1
    lifted = np.r_[ha, hb + np.where(hb < 6.0, 50.0, 0.0)]  # the second tower's foot gone
    keep = lifted < 60.0
    assert (split_masts(xyz[keep], lifted[keep], linkage=LINKAGE, prominence=PROMINENCE, min_points=20) == 0).all()
    assert (split_masts(xyz, hag, linkage=LINKAGE, prominence=PROMINENCE, min_points=len(xyz) // 2 + 1) == 0).all()


def test_prominence_zero_never_splits():
    a, ha = tower_returns("donau", 0.0, 0.8, 1)
    b, hb = tower_returns("donau", 12.0, 0.8, 2, height=HEIGHTS["donau"][0] + 2.0)
    labels = split_masts(np.r_[a, b], np.r_[ha, hb], linkage=LINKAGE, prominence=0.0)
    assert (labels == 0).all()


def test_a_shrub_or_a_stray_point_is_no_mast():
    """Points under a tower's band, or too few or too short in it, make no mast."""
    xyz, hag = tower_returns("small_lattice", 0.0, 0.0, 1)
    assert len(mast_bodies(xyz, hag, LINKAGE)) == 1
    shrub = np.c_[np.full(6, 8.0), np.zeros(6), np.linspace(1.5, 2.5, 6)]
    stray = np.array([[-9.0, 0.0, 4.0], [-9.0, 0.5, 5.0]])
    more = np.r_[xyz, shrub, stray]
    assert len(mast_bodies(more, more[:, 2], LINKAGE)) == 1
    assert (split_masts(more, more[:, 2], linkage=LINKAGE, prominence=PROMINENCE) == 0).all()
