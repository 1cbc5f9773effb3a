"""Tests of towerpipe.evaluation.truth: a labelled zone's true towers and labelled points."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from towerpipe.errors import InputError
from towerpipe.evaluation.truth import zone_labels, zone_truth


def test_labelled_blocks_without_a_truth_file_are_scored_by_their_class_15(tmp_path):
    """An agency's own labelled blocks have no towers_truth.gpkg: the towers their points labelled
    15 are the truth (all blocks together: a tower across an edge is one); with no label at all
    the message says there is nothing to score against."""
    rng = np.random.default_rng(0)
    d = tmp_path / "agency"
    d.mkdir()

    def block(name, x0, towers):
        pts = [np.c_[rng.uniform(x0, x0 + 100, 500), rng.uniform(0, 100, 500), rng.uniform(0, 1, 500), np.full(500, 2)]]
        for tx, ty, lo, hi, *count in towers:  # a column of labelled points, cut at the block's edge
            xs = rng.uniform(tx - 1.5, tx + 1.5, count[0] if count else 200)
            keep = (xs >= x0) & (xs < x0 + 100)
            pts.append(
                np.c_[
                    xs[keep],
                    rng.uniform(ty - 1.5, ty + 1.5, keep.sum()),
                    rng.uniform(lo, hi, keep.sum()),
                    np.full(keep.sum(), 15),
                ]
            )
        a = np.vstack(pts)
        las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
        las.header.offsets, las.header.scales = [400000, 4600000, 0], [0.01, 0.01, 0.01]
        las.x, las.y, las.z = a[:, 0] + 400000, a[:, 1] + 4600000, a[:, 2]
        las.classification = a[:, 3].astype(np.uint8)
        las.write(d / f"{name}.laz")

    block("a", 0, [(30, 30, 0, 25), (100, 60, 0, 30)])  # the second stands across the edge
    block("b", 100, [(100, 60, 0, 30), (140, 20, 3, 3.1, 1)])  # and a stray labelled point
    truth = zone_truth(d, min_points=20)
    edge = [int(((las.classification == 15) & (las.x > 400050)).sum()) for las in map(laspy.read, sorted(d.glob("*")))]
    assert min(edge) > 0  # both blocks hold a part of it
    assert len(truth) == 2 and sorted(truth["n_points"]) == sorted([200, sum(edge) - 1])
    assert truth["height_m"].min() > 20  # each cluster's own height, not the rise over the zone's lowest point
    assert len(zone_truth(d)) == 3  # every labelled cluster, the stray point too
    assert not (d / "towers_truth.gpkg").exists()
    both, labels = zone_labels(d, min_points=20)  # the blocks read once for the truth and the labels
    assert both["n_points"].tolist() == truth["n_points"].tolist()
    for name, idx in labels.items():
        np.testing.assert_array_equal(idx, np.flatnonzero(laspy.read(d / f"{name}.laz").classification == 15))
    assert sorted(labels) == ["a", "b"]
    for f in d.glob("*.laz"):
        las = laspy.read(f)
        las.classification = np.full(len(las.points), 2, np.uint8)
        las.write(f)
    with pytest.raises(InputError, match="nothing to score against"):
        zone_truth(d)
