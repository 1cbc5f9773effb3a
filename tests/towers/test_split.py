"""Tests of towerpipe.towers.split: the parts rule 9 judges instead of a dropped cluster."""

from __future__ import annotations

import numpy as np

from towerpipe.towers.split import RELINK, split_parts


def _labels_by(groups):
    """A clustering that labels each point by ``groups[point]`` (-1: no cluster)."""
    return lambda idx: np.asarray([groups[i] for i in idx], dtype=np.int64)


def test_the_first_threshold_that_gives_a_part_decides_and_the_rest_go_with_the_parts():
    g = np.arange(6)
    prob = np.array([0.9, 0.9, 0.6, 0.6, 0.4, 0.8])
    cluster = _labels_by([0, 0, -1, -1, -1, 1])
    parts = split_parts(g, prob, cluster, (0.5, 0.7, RELINK), relink=_labels_by([0] * 6))
    assert [p.tolist() for p, _ in parts] == [[0, 1], [5]]
    assert all(rest == (0.7, RELINK) for _, rest in parts)
    none = split_parts(g, prob, _labels_by([-1] * 6), (0.5, 0.7), relink=_labels_by([0] * 6))
    assert none == []  # no threshold gives a part, and no relink step is asked for


def test_the_relink_counts_only_when_it_parts_the_cluster():
    g = np.array([3, 4, 5, 6])
    prob = np.full(7, 0.9)
    nothing = _labels_by([-1] * 7)
    whole = split_parts(g, prob, nothing, (0.5, RELINK), relink=_labels_by([0] * 7))
    assert whole == []  # one part, the cluster itself: no split
    trimmed = split_parts(g, prob, nothing, (0.5, RELINK), relink=_labels_by([9, 9, 9, 0, 0, 0, -1]))
    assert [(p.tolist(), rest) for p, rest in trimmed] == [([3, 4, 5], ())]  # its loose edge falls away
    two = split_parts(g, prob, nothing, (RELINK,), relink=_labels_by([9, 9, 9, 0, 1, 1, 0]))
    assert [p.tolist() for p, _ in two] == [[3, 6], [4, 5]]
    assert split_parts(g, prob, nothing, (RELINK,), relink=None) == []  # off (towers.split_linkage 0)
