"""Tests of towerpipe.products.qa.delivery_classes: the delivery's own classes on the QA page."""

from __future__ import annotations

import numpy as np

from towerpipe.classes import USER_DEFINED_MIN
from towerpipe.products.qa.delivery_classes import user_class_rows, user_classes, zone_user_classes


def test_each_class_of_the_delivery_own_with_its_points_and_highest_point():
    cls = np.array([2, 5, 63, 64, 65, 65, 65, 200], np.uint8)
    hag = np.array([0.0, 12.0, 40.0, 3.5, -2.0, 81.25, np.nan, 0.5])
    got = user_classes(cls, hag)
    assert list(got) == [64, 65, 200]  # 63 is reserved by LAS 1.4, not the delivery's
    assert got[65] == {"points": 3, "hag_max": 81.25}  # a point of unknown height does not hide the others
    assert got[64] == {"points": 1, "hag_max": 3.5} and min(got) >= USER_DEFINED_MIN


def test_heights_unknown_and_blocks_without_such_classes():
    cls = np.array([65, 65, 2], np.uint8)
    assert user_classes(cls, None) == {65: {"points": 2, "hag_max": None}}
    assert user_classes(cls, np.array([np.nan, np.nan, 0.0])) == {65: {"points": 2, "hag_max": None}}
    assert user_classes(np.array([1, 2, 5, 15], np.uint8), np.zeros(4)) == {}


def test_rows_name_the_class_and_how_high_it_reaches():
    rows = user_class_rows({65: {"points": 412, "hag_max": 83.46}, 66: {"points": 3, "hag_max": None}})
    assert rows == [
        ("input: class 65, the delivery's own, taken as any point (up to 83.5 m above the ground)", 412),
        ("input: class 66, the delivery's own, taken as any point", 3),
    ]


def test_the_zone_sums_its_blocks_classes():
    docs = [
        {"user_classes": {"65": {"points": 3, "hag_max": 80.0}, "208": {"points": 7, "hag_max": None}}},
        {"user_classes": {"65": {"points": 2, "hag_max": 12.5}}},
        {"user_classes": {}},
        {},  # a page of a version before the rows
    ]
    assert zone_user_classes(docs) == [
        {"class": 65, "blocks": 2, "points": 5, "hag_max": 80.0},
        {"class": 208, "blocks": 1, "points": 7, "hag_max": None},
    ]
    assert zone_user_classes([]) == []
