"""Tests of towerpipe.towers.registry: stable tower ids from run to run."""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from test_towers import BOUNDS, X0, Y0, pred_pair, synthetic_tower

from conftest import extract
from towerpipe.products.gpkg import write_towers_gpkg
from towerpipe.products.registry_file import published_reviews, read_registry, reviewed_towers, write_registry
from towerpipe.towers.registry import (
    ACTIVE,
    MATCH_DISTANCE,
    VANISHED,
    assign_ids,
    location_id,
    unique_ids,
    update_registry,
    vanished,
)

CRS = "EPSG:25831"
T1 = pd.Timestamp("2024-05-01T12:00:00Z")
T2 = pd.Timestamp("2024-06-01T12:00:00Z")


def test_location_id_reads_as_easting_northing_and_stays_exact_in_float64():
    assert location_id(400112.6, 4600325.4) == 40011304600325
    assert location_id(689_700.2, 6_735_950.7) == 68970006735951
    big = location_id(89_999_999.0, 99_999_999.0)
    assert big < 2**53 and float(big) == big
    assert location_id(-10.0, -20.0) != location_id(10.0, 20.0)  # negative coordinates stay distinct
    assert location_id(-10.0, -20.0) > 0


def box(cx, cy, half=4.0):
    return shapely.box(cx - half, cy - half, cx + half, cy + half)


def registry_of(rows):
    return gpd.GeoDataFrame(
        [
            {
                "tower_id": tid,
                "status": status,
                "block": "b",
                "centroid_x": x,
                "centroid_y": y,
                "height_m": 30.0,
                "first_seen": T1,
                "last_seen": T1,
                "vanished_since": pd.NaT,
                "review_status": review,
            }
            for tid, x, y, status, review in rows
        ],
        geometry=[box(x, y) for _, x, y, _, _ in rows],
        crs=CRS,
    )


def test_assign_ids_keeps_registered_ids_and_makes_new_ones():
    reg = registry_of(
        [(111, X0 + 100, Y0 + 100, ACTIVE, "confirmed"), (222, X0 + 300, Y0 + 100, VANISHED, "unreviewed")]
    )
    feet = [
        box(X0 + 103, Y0 + 102),  # footprints intersect: the registered id
        box(X0 + 300 + 4.5 + 4.5 + 3, Y0 + 100),  # no overlap, centroid 12 m away: new
        box(X0 + 307.5, Y0 + 100),  # overlap with the vanished tower: found again
        box(X0 + 500, Y0 + 500),
    ]  # nothing near: new
    ids, first, review = assign_ids(feet, reg)
    assert ids[0] == 111 and first[0] == T1 and review[0] == "confirmed"
    assert ids[2] == 222 and review[2] == "unreviewed"
    assert ids[1] == location_id(X0 + 312, Y0 + 100) and first[1] is None and review[1] == "unreviewed"
    assert ids[3] == location_id(X0 + 500, Y0 + 500)
    # one to one: of two towers on one registered tower, the nearer keeps its id
    ids, _, _ = assign_ids([box(X0 + 102, Y0 + 100), box(X0 + 101, Y0 + 100)], reg)
    assert ids[1] == 111 and ids[0] not in (111, 222)
    # by distance alone
    ids, _, _ = assign_ids([box(X0 + 100 + MATCH_DISTANCE - 0.1 + 8.0, Y0 + 100, half=0.5)], reg)
    assert ids[0] != 111
    ids, _, _ = assign_ids([box(X0 + 100 + MATCH_DISTANCE - 0.1, Y0 + 100, half=0.5)], reg)
    assert ids[0] == 111


def test_a_new_id_never_takes_a_registered_one():
    """A registered tower drifted away from where its id was made: a new tower there gets the next metre."""
    drifted = location_id(X0 + 50, Y0 + 50)
    reg = registry_of([(drifted, X0 + 80, Y0 + 50, ACTIVE, "unreviewed")])
    ids, _, _ = assign_ids([box(X0 + 50, Y0 + 50)], reg)
    assert ids[0] == location_id(X0 + 50, Y0 + 51)
    assert assign_ids([], reg)[0].shape == (0,)
    assert list(assign_ids([box(X0 + 50, Y0 + 50)], None)[0]) == [drifted]


def test_ids_survive_a_shift_that_changes_the_location_id():
    """Rerun with other thresholds: the tower's centroid moves by a metre, its id stays."""
    xyz, hag = synthetic_tower(X0 + 50.3, Y0 + 50.3, seed=1)
    first = extract([pred_pair(xyz, hag, 0.9, ["b1"])], "b1", BOUNDS, zone="z1").towers
    reg = update_registry(read_registry(), first, run_time=T1)
    moved = xyz + [0.9, -0.8, 0.0]
    plain = extract([pred_pair(moved, hag, 0.9, ["b1"])], "b1", BOUNDS, zone="z1").towers
    kept = extract([pred_pair(moved, hag, 0.9, ["b1"])], "b1", BOUNDS, zone="renamed", registry=reg).towers
    assert plain.iloc[0]["tower_id"] != first.iloc[0]["tower_id"]  # the location alone would change it
    assert kept.iloc[0]["tower_id"] == first.iloc[0]["tower_id"]
    assert kept.iloc[0]["first_seen"] == first.iloc[0]["first_seen"]


def test_update_registry_vanished_failed_blocks_and_found_again(tmp_path):
    a, ha = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    b, hb = synthetic_tower(X0 + 300, Y0 + 50, seed=2)
    both = extract(
        [pred_pair(np.r_[a, b], np.r_[ha, hb], 0.9, ["b1"])], "b1", BOUNDS, zone="z", processed_at=str(T1)
    ).towers
    reg = update_registry(read_registry(), both, run_time=T1)
    assert list(reg["status"]) == [ACTIVE, ACTIVE] and (reg["first_seen"] == T1).all()
    only_a = both.iloc[:1]
    # block b1 failed this time: its towers are unknown, not vanished
    kept = update_registry(reg, only_a.iloc[:0], run_time=T2, keep_blocks=["b1"])
    assert list(kept["status"]) == [ACTIVE, ACTIVE] and len(vanished(kept)) == 0
    # b1 completed without the second tower: it vanished, listed with when
    after = update_registry(reg, only_a, run_time=T2)
    gone = vanished(after)
    assert list(gone["tower_id"]) == [both.iloc[1]["tower_id"]] and gone.iloc[0]["vanished_since"] == T2
    assert after.loc[after["status"] == ACTIVE, "last_seen"].iloc[0] == T2
    # a later run still lists it (vanished since T2), and finds it again with its id
    later = update_registry(after, only_a, run_time=T2 + pd.Timedelta(days=1))
    assert vanished(later).iloc[0]["vanished_since"] == T2
    again = extract([pred_pair(b, hb, 0.9, ["b1"])], "b1", BOUNDS, zone="z", registry=later).towers
    assert again.iloc[0]["tower_id"] == both.iloc[1]["tower_id"]
    now = gpd.GeoDataFrame(pd.concat([only_a, again], ignore_index=True), crs=again.crs)
    back = update_registry(later, now, run_time=T2 + pd.Timedelta(days=2))
    assert len(vanished(back)) == 0 and back.set_index("tower_id").loc[again.iloc[0]["tower_id"], "first_seen"] == T1
    # the file round trip
    path = write_registry(tmp_path / "registry.gpkg", back, CRS)
    read = read_registry(tmp_path / "missing.gpkg", path)
    pd.testing.assert_frame_equal(read.drop(columns="geometry"), back.drop(columns="geometry"), check_dtype=False)


def test_registry_from_the_published_file_and_analyst_reviews(tmp_path):
    """Without its registry file (work/ deleted), the zone's published towers.gpkg seeds the
    registry; review statuses analysts set there are carried into it."""
    a, ha = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    towers = extract([pred_pair(a, ha, 0.9, ["b1"])], "b1", BOUNDS, zone="z").towers
    reg = update_registry(read_registry(), towers, run_time=T1)
    edited = towers.copy()
    edited["review_status"] = "rejected"
    published = write_towers_gpkg(tmp_path / "towers.gpkg", edited, vanished=vanished(reg))
    seeded = read_registry(tmp_path / "registry.gpkg", published)
    assert list(seeded["tower_id"]) == list(towers["tower_id"]) and seeded.iloc[0]["status"] == ACTIVE
    assert published_reviews(published, reg) == {int(towers.iloc[0]["tower_id"]): "rejected"}
    # what the QA index reads: the reviewed towers of the file, whatever the registry holds
    assert reviewed_towers(published) == {int(towers.iloc[0]["tower_id"]): "rejected"}
    assert reviewed_towers(tmp_path / "nothing.gpkg") == {} and reviewed_towers(None) == {}
    updated = update_registry(reg, towers, run_time=T2, reviews=published_reviews(published, reg))
    assert updated.iloc[0]["review_status"] == "rejected"
    # a file of an older version (text ids) starts an empty registry
    old = towers.copy()
    old["tower_id"] = ["T_z_400050_4600050"]
    old_path = tmp_path / "old.gpkg"
    old.drop(columns=["first_seen"]).to_file(old_path, layer="towers", engine="pyogrio")
    assert len(read_registry(old_path)) == 0
    assert len(read_registry()) == 0 and len(read_registry(None, tmp_path / "nothing.gpkg")) == 0


def test_unique_ids_keeps_the_nearer_tower():
    reg_id = location_id(X0 + 100, Y0 + 100)
    towers = gpd.GeoDataFrame(
        {
            "tower_id": [reg_id, reg_id, 7],
            "block": ["a", "b", "c"],
            "centroid_x": [X0 + 103.0, X0 + 101.0, X0],
            "centroid_y": [Y0 + 100.0] * 3,
        },
        geometry=[box(X0 + 103, Y0 + 100), box(X0 + 101, Y0 + 100), box(X0, Y0)],
        crs=CRS,
    )
    out = unique_ids(towers)
    assert out["tower_id"].is_unique and len(out) == 3
    assert out.set_index("block").loc["b", "tower_id"] == reg_id
    assert unique_ids(out) is out
