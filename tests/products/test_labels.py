"""Tests of towerpipe.products.labels: the probability, tower id and class each point of a block gets."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import write_pred
from towerpipe.errors import InputError
from towerpipe.io.members import save_members
from towerpipe.products.labels import block_labels, block_probabilities, relabel


def test_relabel_rules():
    cls = np.array([1, 2, 15, 15, 6, 65, 2], np.uint8)
    prob = np.array([0.0, 0.7, 0.9, 0.2, 0.5, 0.0, 0.49], np.float32)
    np.testing.assert_array_equal(relabel(cls, prob, 0.5), [1, 15, 15, 1, 15, 65, 2])
    withheld = np.array([0, 0, 0, 1, 0, 0, 0], bool)  # a withheld 15 is never taken back
    np.testing.assert_array_equal(relabel(cls, prob, 0.5, withheld=withheld), [1, 15, 15, 15, 15, 65, 2])


def test_relabel_follows_the_reported_towers_not_the_threshold():
    cls = np.array([1, 1, 15, 5], np.uint8)
    prob = np.array([0.9, 0.1, 0.9, 0.1], np.float32)
    tower = np.array([False, True, False, True])  # a confident point outside every tower stays 1
    np.testing.assert_array_equal(relabel(cls, prob, 0.5, tower=tower), [1, 15, 1, 15])
    assert relabel(cls, prob, 0.5, tower=tower).dtype == cls.dtype


def test_block_probabilities_filters_block_and_checks_range(tmp_path):
    p1 = write_pred(tmp_path / "t1.npz", "a", [0, 5, 9], [0.1, 0.9, 0.6], blocks=["a", "b"], block_id=[0, 0, 1])
    prob, info = block_probabilities([p1], 10, block="a")
    np.testing.assert_array_equal(prob, np.array([0.1, 0, 0, 0, 0, 0.9, 0, 0, 0, 0], np.float32))
    assert info == {"block": "a", "pred_files": 1, "pred_points": 2}
    with pytest.raises(InputError, match="out of range"):
        block_probabilities([p1], 5, block="a")


def test_block_probabilities_takes_the_highest_of_every_window_and_tile(tmp_path):
    # a point seen twice in one file (two windows) and again by the neighbouring tile
    p1 = write_pred(tmp_path / "t1.npz", "a", [3, 3, 7], [0.2, 0.8, 0.4])
    p2 = write_pred(tmp_path / "t2.npz", "a", [3, 7], [0.5, 0.6])
    prob, info = block_probabilities([p1, p2], 8)
    assert info["block"] == "a" and info["pred_points"] == 5
    np.testing.assert_allclose(prob[[3, 7]], [0.8, 0.6])
    assert np.count_nonzero(prob) == 2


def test_block_probabilities_needs_the_block_named_when_files_disagree(tmp_path):
    p1 = write_pred(tmp_path / "t1.npz", "a", [1], [0.5])
    p2 = write_pred(tmp_path / "t2.npz", "b", [1], [0.5])
    with pytest.raises(InputError, match="several blocks.*block="):
        block_probabilities([p1, p2], 4, block_path="flight/b.laz")
    assert block_probabilities([p1, p2], 4, block="b")[1]["pred_points"] == 1


def test_block_probabilities_refuses_non_finite_probabilities(tmp_path):
    p1 = write_pred(tmp_path / "t1.npz", "a", [0, 1], [0.5, np.nan])
    with pytest.raises(InputError, match="non-finite.*rerun the inference"):
        block_probabilities([p1], 4)


def test_block_labels_classes_the_towers_points_chunk_by_chunk(tmp_path):
    n = 10
    pred = write_pred(tmp_path / "t1.npz", "a", [1, 2, 3, 8], [0.9, 0.2, 0.7, 0.95])
    members = tmp_path / "members.npz"
    # tower 7 holds points 1 and 2 of block a (2 under the threshold) and a point of block b
    save_members(members, {7: (np.array(["a", "a", "b"]), np.array([1, 2, 0]))})
    labels = block_labels([pred], n, block="a", tower_points=[members])
    np.testing.assert_array_equal(np.flatnonzero(labels.tower_ids), [1, 2])
    assert labels.tower_ids[1] == labels.tower_ids[2] == 7
    cls = np.array([1, 1, 1, 1, 2, 15, 5, 5, 1, 1], np.uint8)
    whole = labels.classes(cls, 0.5)
    np.testing.assert_array_equal(whole, [1, 15, 15, 1, 2, 1, 5, 5, 1, 1])  # 3 and 8 are in no tower
    chunks = [labels.classes(cls[s : s + 3], 0.5, start=s) for s in range(0, n, 3)]
    np.testing.assert_array_equal(np.concatenate(chunks), whole)


def test_block_labels_without_tower_files_uses_the_threshold(tmp_path):
    pred = write_pred(tmp_path / "t1.npz", "a", [1, 2], [0.9, 0.2])
    labels = block_labels([pred], 4)
    assert labels.tower is None and not labels.tower_ids.any()
    np.testing.assert_array_equal(labels.classes(np.ones(4, np.uint8), 0.5), [1, 15, 1, 1])
