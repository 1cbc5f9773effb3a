"""The tower record (:mod:`towerpipe.towers.records`): what a row says of an accepted tower."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely

from towerpipe.towers.records import TOWER_COLUMNS, tower_record, towers_frame

STAMP = pd.Timestamp("2026-11-28T12:00:00", tz="UTC")


def record(**kw):
    z = np.array([100.0, 110.0, 130.004])
    hag = np.array([0.02, 10.0, 30.0])
    args = dict(
        tower_id=7,
        zone="z",
        block="b",
        block_bounds=(0.0, 0.0, 100.0, 100.0),
        touched=["b", "c"],
        n_points=25,
        shape_score=0.97,
        shape_view="object",
        wire_support=float("nan"),
        review_status="unreviewed",
        first_seen=None,
        processed_at=STAMP,
        source_files={"b": "in/b.laz"},
        model_meta={"name": "m", "version": "3"},
    )
    args.update(kw)
    return tower_record(shapely.box(10.0, 20.0, 14.0, 30.0), z, hag, np.array([0.5, 0.9, 0.7]), **args)


def test_a_record_measures_its_tower():
    r = record()
    assert (r["centroid_x"], r["centroid_y"]) == (12.0, 25.0)
    assert (r["footprint_width_m"], r["footprint_length_m"], r["footprint_area_m2"]) == (4.0, 10.0, 40.0)
    assert r["edge_distance_m"] == 12.0  # to the block's west edge
    assert r["height_m"] == round(r["top_z"] - r["base_z"], 2) and r["top_z"] == 130.0
    assert (r["prob_mean"], r["prob_max"], r["n_points"]) == (pytest.approx(0.7), 0.9, 25)
    assert r["blocks"] == "b;c" and r["source_files"].endswith("in/b.laz")  # c has no file listed


def test_first_seen_is_now_unless_the_registry_knows_the_tower():
    assert record()["first_seen"] == STAMP
    assert record(first_seen=pd.NaT)["first_seen"] == STAMP
    old = pd.Timestamp("2025-01-01", tz="UTC")
    assert record(first_seen=old)["first_seen"] == old


def test_the_frame_is_sorted_by_id_and_empty_with_the_full_schema():
    rows = [record(tower_id=9), record(tower_id=3)]
    f = towers_frame(rows, [shapely.box(0, 0, 1, 1)] * 2, "EPSG:2154")
    assert f["tower_id"].tolist() == [3, 9]
    assert list(f.columns[:-1]) == list(TOWER_COLUMNS)
    empty = towers_frame([], [], "EPSG:2154")
    assert len(empty) == 0 and list(empty.columns[:-1]) == list(TOWER_COLUMNS)


def test_the_shape_view_is_kept_and_null_without_the_shape_check():
    rows = [record(tower_id=1, shape_view="core"), record(tower_id=2, shape_view=None, shape_score=float("nan"))]
    f = towers_frame(rows, [shapely.box(0, 0, 1, 1)] * 2, "EPSG:2154")
    assert f["shape_view"].tolist() == ["core", None]
