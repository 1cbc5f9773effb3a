"""Tests of towerpipe.towers.extract, .cluster and .matching: clustering predicted points into
tower records, the tower rules, and matching towers; and of the tower-points files (towerpipe.io.members)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely

from conftest import LENIENT_TOWERS, REPO, extract, tower_rules
from towerpipe.config import SCHEMA_FILE, TowersConfig, load_yaml
from towerpipe.errors import InputError
from towerpipe.io.members import member_mask, save_members
from towerpipe.io.predictions import save_pred
from towerpipe.towers.cluster import cluster_towers
from towerpipe.towers.extract import extract_towers
from towerpipe.towers.matching import match_towers, towers_from_labels
from towerpipe.towers.records import TOWER_COLUMNS
from towerpipe.towers.registry import location_id

X0, Y0 = 400_000.0, 4_600_000.0
CRS = "EPSG:25831"
MODEL = {"name": "pointnet_l", "version": "1.2.0"}
STAMP = "2024-05-01T12:00:00+00:00"


def synthetic_tower(
    cx: float,
    cy: float,
    *,
    height: float = 30.0,
    base_z: float = 100.0,
    half_base: float = 3.0,
    half_top: float = 1.0,
    arm: float = 7.0,
    step: float = 0.4,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Points of a lattice tower: four converging legs and a crossarm; (xyz, hag)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, height, step)
    half = half_base + (half_top - half_base) * t / height
    parts = [
        np.stack([cx + sx * half, cy + sy * half, base_z + t], axis=1)
        for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1))
    ]
    a = np.arange(-arm, arm + step, step)
    parts.append(np.stack([cx + a, np.full_like(a, cy), np.full_like(a, base_z + 0.8 * height)], axis=1))
    xyz = np.concatenate(parts) + rng.normal(0.0, 0.03, (sum(len(p) for p in parts), 3))
    return xyz, (xyz[:, 2] - base_z).astype(np.float32)


def pred_pair(
    xyz: np.ndarray,
    hag: np.ndarray,
    prob: np.ndarray | float,
    blocks: list[str],
    block_id: np.ndarray | int = 0,
    tile: str = "t0",
) -> tuple[dict, dict]:
    """(arrays, meta) as in a prediction file."""
    n = len(xyz)
    arrays = {
        "block_id": np.broadcast_to(np.asarray(block_id, dtype=np.int32), (n,)).copy(),
        "point_index": np.arange(n, dtype=np.int64),
        "x": xyz[:, 0].copy(),
        "y": xyz[:, 1].copy(),
        "z": xyz[:, 2].copy(),
        "hag": np.asarray(hag, dtype=np.float32),
        "prob": np.broadcast_to(np.asarray(prob, dtype=np.float32), (n,)).copy(),
    }
    meta = {
        "zone": "z1",
        "block": blocks[0],
        "tile": tile,
        "blocks": blocks,
        "crs_wkt": CRS,
        "core_bounds": [0, 0, 0, 0],
        "model": MODEL,
    }
    return arrays, meta


def scene() -> tuple[np.ndarray, np.ndarray]:
    """Two towers 150 m apart plus scattered low-probability clutter is added by callers."""
    a, ha = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    b, hb = synthetic_tower(X0 + 200, Y0 + 60, height=42.0, base_z=110.0, seed=2)
    return np.concatenate([a, b]), np.concatenate([ha, hb])


BOUNDS = (X0, Y0, X0 + 500, Y0 + 500)


def test_two_towers_records():
    xyz, hag = scene()
    rng = np.random.default_rng(5)
    clutter = np.column_stack(
        [rng.uniform(X0, X0 + 500, 300), rng.uniform(Y0, Y0 + 500, 300), rng.uniform(100, 120, 300)]
    )
    allxyz = np.concatenate([xyz, clutter])
    allhag = np.concatenate([hag, (clutter[:, 2] - 100).astype(np.float32)])
    prob = np.concatenate([np.full(len(xyz), 0.9), np.full(len(clutter), 0.2)])
    gdf = extract_towers(
        [pred_pair(allxyz, allhag, prob, ["b1"])],
        "b1",
        BOUNDS,
        tower_rules(**LENIENT_TOWERS),
        zone="z1",
        point_threshold=None,
        model_meta=MODEL,
        source_files={"b1": "/data/b1.laz"},
        processed_at=STAMP,
    ).towers
    assert len(gdf) == 2
    assert list(gdf.columns) == list(TOWER_COLUMNS) + ["geometry"]
    assert str(gdf.crs.to_epsg()) == "25831"
    gdf = gdf.sort_values("centroid_x").reset_index(drop=True)
    np.testing.assert_allclose(gdf["centroid_x"], [X0 + 50, X0 + 200], atol=0.3)
    np.testing.assert_allclose(gdf["centroid_y"], [Y0 + 50, Y0 + 60], atol=0.3)
    np.testing.assert_allclose(gdf["height_m"], [30.0, 42.0], atol=0.5)
    np.testing.assert_allclose(gdf["base_z"], [100.0, 110.0], atol=0.1)
    # the height is the top above the base, to the cm; values are rounded to the cm
    np.testing.assert_allclose(gdf["height_m"], gdf["top_z"] - gdf["base_z"], atol=0.005)
    for col in ("height_m", "top_z", "base_z", "centroid_x", "centroid_y", "footprint_area_m2"):
        np.testing.assert_array_equal(gdf[col], gdf[col].round(2))
    np.testing.assert_allclose(gdf["prob_mean"], 0.9, atol=1e-6)
    n_a = len(synthetic_tower(X0 + 50, Y0 + 50, seed=1)[0])
    assert gdf.loc[0, "n_points"] == n_a
    # a new tower's id: its centroid on a 1 m grid, easting then northing; no zone name in it
    assert gdf.loc[0, "tower_id"] == location_id(gdf.loc[0, "centroid_x"], gdf.loc[0, "centroid_y"])
    assert gdf.loc[0, "tower_id"] == 40005004600050
    assert set(gdf["source_files"]) == {"/data/b1.laz"}
    assert set(gdf["model_version"]) == {"1.2.0"}
    assert set(gdf["processed_at"]) == {pd.Timestamp(STAMP)} == set(gdf["first_seen"])
    assert set(gdf["review_status"]) == {"unreviewed"}
    assert gdf.geometry.is_valid.all() and (gdf.geometry.geom_type == "Polygon").all()
    # footprint: legs 6 m apart, crossarm 14 m long
    assert gdf.loc[0, "footprint_length_m"] == pytest.approx(14.0, abs=0.5)
    assert gdf.loc[0, "footprint_width_m"] == pytest.approx(6.0, abs=0.5)
    assert gdf.loc[0, "edge_distance_m"] == pytest.approx(50.0, abs=0.3)


def test_tower_rules_are_the_config_schemas():
    """TowersConfig holds no defaults: a config without a towers section gets the schema's."""
    schema = load_yaml(REPO / SCHEMA_FILE, "schema")["properties"]["towers"]["properties"]
    rules = tower_rules()
    assert isinstance(rules, TowersConfig)

    def default(prop):  # an object's default is its properties' (the validator fills them in)
        if prop.get("type") == "object":
            return {k: default(v) for k, v in prop["properties"].items()}
        return prop["default"]

    assert {k: getattr(rules, k) for k in vars(rules)} == {k: default(schema[k]) for k in vars(rules)}
    assert tower_rules(min_core_prob=0.9).min_core_prob == 0.9


def test_ids_independent_of_order_and_file_split():
    xyz, hag = scene()
    ref = extract([pred_pair(xyz, hag, 0.9, ["b1"])], "b1", BOUNDS, zone="z1", processed_at=STAMP).towers
    perm = np.random.default_rng(3).permutation(len(xyz))
    half = len(perm) // 2
    p1 = pred_pair(xyz[perm[:half]], hag[perm[:half]], 0.9, ["b1"], tile="t1")
    p2 = pred_pair(xyz[perm[half:]], hag[perm[half:]], 0.9, ["b1"], tile="t2")
    p2[0]["point_index"] += half
    other = extract([p2, p1], "b1", BOUNDS, zone="z1", processed_at=STAMP).towers
    assert list(ref["tower_id"]) == list(other["tower_id"])
    assert all(a.equals(b) for a, b in zip(ref.geometry, other.geometry))
    # the same file given twice is not counted twice
    twice = extract([p1, p2, p1], "b1", BOUNDS, zone="z1", processed_at=STAMP).towers
    assert list(twice["n_points"]) == list(ref["n_points"])


def test_tower_across_block_edge_reported_once():
    edge = X0 + 250.0
    xyz, hag = synthetic_tower(edge + 0.6, Y0 + 100)  # centroid just east of the edge
    west = xyz[:, 0] < edge
    arrays, meta = pred_pair(xyz, hag, 0.95, ["bw", "be"], block_id=np.where(west, 0, 1))
    bw = (X0, Y0, edge, Y0 + 500)
    be = (edge, Y0, X0 + 500, Y0 + 500)
    # each block's job sees its own and its neighbour's predictions
    west_found = extract([(arrays, meta)], "bw", bw, zone="z1", processed_at=STAMP)
    east_found = extract([(arrays, meta)], "be", be, zone="z1", processed_at=STAMP)
    west_towers, west_nb = west_found.towers, west_found.neighbours
    east_towers, east_nb = east_found.towers, east_found.neighbours
    assert len(west_towers) == 0
    assert len(east_towers) == 1
    row = east_towers.iloc[0]
    # the west block knows the tower it touches is the east block's (for its QA), the east one owns it
    assert [t["tower_id"] for t in west_nb] == [row["tower_id"]] and east_nb == []
    assert shapely.from_wkt(west_nb[0]["footprint_wkt"]).equals_exact(east_towers.geometry.iloc[0], 1e-6)
    assert row["block"] == "be" and row["blocks"] == "be;bw"
    assert row["n_points"] == len(xyz)
    assert 0 < row["edge_distance_m"] < 1.0


def test_half_open_bounds_exactly_one_owner():
    xyz, hag = synthetic_tower(X0 + 250.0, Y0 + 100)
    arrays, meta = pred_pair(xyz, hag, 0.9, ["b"])
    cx = extract([(arrays, meta)], "b", BOUNDS, zone="z", processed_at=STAMP).towers.iloc[0]["centroid_x"]
    left = extract([(arrays, meta)], "b", (X0, Y0, cx, Y0 + 500), zone="z").towers
    right = extract([(arrays, meta)], "b", (cx, Y0, X0 + 500, Y0 + 500), zone="z").towers
    assert (len(left), len(right)) == (0, 1)


def test_filters_and_threshold():
    big, hb = synthetic_tower(X0 + 50, Y0 + 50)
    low, hl = synthetic_tower(X0 + 150, Y0 + 50, height=6.0, arm=2.0)  # too low
    few, hf = synthetic_tower(X0 + 250, Y0 + 50, height=12.0, step=3.0, arm=0)  # too few points (spaced 3 m
    few = few[:8]  # apart: also not linked)
    hf = hf[:8]
    weak, hw = synthetic_tower(X0 + 350, Y0 + 50)  # low probability
    xyz = np.concatenate([big, low, few, weak])
    hag = np.concatenate([hb, hl, hf, hw])
    prob = np.concatenate([np.full(len(big) + len(low) + len(few), 0.8), np.full(len(weak), 0.3)])
    gdf = extract(
        [pred_pair(xyz, hag, prob, ["b"])], "b", BOUNDS, zone="z", min_points=20, min_height=10.0, threshold=0.5
    ).towers
    assert len(gdf) == 1 and gdf.iloc[0]["centroid_x"] == pytest.approx(X0 + 50, abs=0.3)
    gdf = extract([pred_pair(xyz, hag, prob, ["b"])], "b", BOUNDS, zone="z", threshold=0.25, min_height=5.0).towers
    assert len(gdf) == 3


def test_towers_without_a_confident_core_are_dropped():
    """A cluster whose probabilities hover above the point threshold is not a tower; one with a
    confident core is, even when most of its points are uncertain."""
    xyz, hag = scene()
    first = xyz[:, 0] < X0 + 120
    rng = np.random.default_rng(3)
    prob = rng.uniform(0.5, 0.85, len(xyz))
    core = ~first & (rng.random(len(xyz)) < 0.15)
    prob[core] = 0.99
    pair = pred_pair(xyz, hag, prob, ["b1"])
    kept = extract([pair], "b1", BOUNDS, zone="z1", min_core_prob=0.9).towers
    assert len(kept) == 1 and kept.iloc[0]["centroid_x"] > X0 + 120
    assert len(extract([pair], "b1", BOUNDS, zone="z1").towers) == 2


def test_a_tall_cluster_needs_the_tall_core_probability():
    """Rule 21: a cluster at least ``wire_min_height`` high needs ``tall_core_prob``, a lower one
    ``min_core_prob`` (the 30 m tower's probabilities hover at 0.5-0.85, its 90th percentile ~0.82)."""
    xyz, hag = scene()
    first = xyz[:, 0] < X0 + 120
    prob = np.random.default_rng(3).uniform(0.5, 0.85, len(xyz))
    prob[~first] = 0.99
    pair = pred_pair(xyz, hag, prob, ["b1"])

    def found(**rules):
        return len(extract([pair], "b1", BOUNDS, zone="z1", min_core_prob=0.9, **rules).towers)

    assert found() == 1  # the 30 m tower's core is under 0.9
    assert found(tall_core_prob=0.8) == 2  # 30 m is tall (wire_min_height 15 m): 0.8 is its bar
    assert found(tall_core_prob=0.8, wire_min_height=35.0) == 1  # not tall: min_core_prob holds
    assert found(tall_core_prob=0.95) == 1  # never more than min_core_prob asks
    assert tower_rules(tall_core_prob=0.2).core_needed(25.0) == 0.2
    shipped = tower_rules().min_core_prob  # the schema's default
    assert tower_rules(tall_core_prob=0.2).core_needed(12.0) == tower_rules().core_needed(25.0) == shipped > 0.2


def test_wire_chain_is_split_into_towers():
    a, ha = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    b, hb = synthetic_tower(X0 + 110, Y0 + 50, seed=2)
    # falsely predicted conductor linking the crossarm tips (sagging line)
    s = np.linspace(0, 1, 150)
    wire = np.column_stack([X0 + 57 + s * 46, np.full_like(s, Y0 + 50), 124 - 6 * np.sin(np.pi * s)])
    xyz = np.concatenate([a, b, wire])
    hag = np.concatenate([ha, hb, (wire[:, 2] - 100).astype(np.float32)])
    labels = cluster_towers(xyz, hag, linkage=2.5, min_points=20, min_height=10.0)
    assert labels.max() == 1
    assert len(np.unique(labels[: len(a)])) == 1 and len(np.unique(labels[len(a) : len(a) + len(b)])) == 1
    assert labels[0] != labels[len(a)]
    assert (labels[len(a) + len(b) + 40 : -40] == -1).all()  # mid-span wire dropped


def test_split_footprints_are_merged():
    xyz, hag = synthetic_tower(X0 + 50, Y0 + 50, arm=0.0)
    # a crossarm detached from the body: 3.5 m from the leg tops (not linked at 2.5 m), but its xy
    # footprint is only 1.5 m from the leg bases
    arm = np.column_stack([np.linspace(X0 + 47, X0 + 53, 30), np.full(30, Y0 + 54.5), np.full(30, 125.0)])
    xyz2 = np.concatenate([xyz, arm])
    hag2 = np.concatenate([hag, np.full(30, 25.0, np.float32)])
    assert cluster_towers(xyz2, hag2, linkage=2.5, merge_gap=0.0, min_points=1, min_height=0).max() == 1
    assert cluster_towers(xyz2, hag2, linkage=2.5, merge_gap=2.0, min_points=1, min_height=0).max() == 0


def test_empty_predictions_give_empty_schema():
    arrays, meta = pred_pair(np.zeros((0, 3)), np.zeros(0), 0.9, ["b"])
    gdf = extract([(arrays, meta)], "b", BOUNDS, zone="z").towers
    assert len(gdf) == 0 and list(gdf.columns) == list(TOWER_COLUMNS) + ["geometry"]
    assert gdf.crs is not None
    assert len(extract([], "b", BOUNDS, zone="z", crs=CRS).towers) == 0


def test_reads_prediction_files(tmp_path):
    xyz, hag = scene()
    arrays, meta = pred_pair(xyz, hag, 0.9, ["b1"])
    meta.update(
        {
            "windows_total": 10,
            "windows_passed_gate": 2,
            "windows_segmented": 2,
            "gate_threshold": 0.5,
            "combine": "max",
            "points_core": len(xyz),
            "points_model_input_core": len(xyz),
            "timings": {},
            "peak_rss_mb": 1.0,
        }
    )
    save_pred(tmp_path / "t.npz", arrays, meta)
    gdf = extract([tmp_path / "t.npz"], "b1", BOUNDS, zone="z1").towers
    assert len(gdf) == 2 and set(gdf["model_name"]) == {"pointnet_l"}


def test_degenerate_footprint_is_buffered():
    # a vertical pole: all points on one xy spot
    z = np.linspace(100, 120, 50)
    xyz = np.column_stack([np.full(50, X0 + 10), np.full(50, Y0 + 10), z])
    gdf = extract([pred_pair(xyz, z - 100, 0.9, ["b"])], "b", BOUNDS, zone="z", min_width=1.0).towers
    assert len(gdf) == 1
    geom = gdf.geometry.iloc[0]
    assert geom.is_valid and geom.geom_type == "Polygon" and geom.area > 0.5


def test_match_towers_one_to_one():
    import geopandas as gpd

    truth = gpd.GeoDataFrame(
        {"id": ["a", "b", "c"]},
        geometry=[shapely.box(0, 0, 6, 6), shapely.box(100, 0, 106, 6), shapely.box(300, 0, 306, 6)],
    )
    pred = gpd.GeoDataFrame(
        {"tower_id": ["p1", "p2", "p3", "p4"]},
        geometry=[
            shapely.box(1, 1, 7, 7),  # overlaps a
            shapely.box(0.5, 0, 6.5, 6),  # also near a: duplicate -> fp
            shapely.box(108, 0, 112, 6),  # centroid 7 m from b, no overlap
            shapely.box(200, 0, 206, 6),
        ],
    )  # nothing
    r = match_towers(pred, truth, max_dist=5.0)
    assert r["tp"] == 1 and r["fp"] == 3 and r["fn"] == 2
    assert r["matches"][0]["pred"] == "p2" and r["matches"][0]["truth"] == "a"  # nearest centroid wins
    assert r["precision"] == pytest.approx(0.25) and r["recall"] == pytest.approx(1 / 3)
    r = match_towers(pred, truth, max_dist=8.0)
    assert r["tp"] == 2 and {m["truth"] for m in r["matches"]} == {"a", "b"}
    empty = match_towers(pred.iloc[:0], truth)
    assert empty["precision"] is None and empty["recall"] == 0.0


def test_towers_from_labels_and_evaluation():
    xyz, hag = scene()
    is_tower = np.ones(len(xyz), dtype=bool)
    truth = towers_from_labels(xyz[:, 0], xyz[:, 1], xyz[:, 2], hag, is_tower, crs=CRS)
    assert len(truth) == 2
    pred = extract([pred_pair(xyz, hag, 0.9, ["b"])], "b", BOUNDS, zone="z").towers
    r = match_towers(pred, truth)
    assert (r["precision"], r["recall"]) == (1.0, 1.0)
    assert max(m["distance_m"] for m in r["matches"]) < 0.5


def test_floating_cluster_is_not_a_tower():
    """A piece of conductor predicted as tower (its lowest point high above ground) is dropped."""
    xyz, hag = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    s = np.linspace(0, 1, 60)
    piece = np.column_stack([X0 + 150 + 12 * s, np.full_like(s, Y0 + 50), 124 + 4 * s])
    allxyz = np.concatenate([xyz, piece])
    allhag = np.concatenate([hag, (piece[:, 2] - 100).astype(np.float32)])
    pair = pred_pair(allxyz, allhag, 0.95, ["b1"])
    # rule 16 off: nothing stands over the piece either (tests/towers/test_plan.py)
    assert len(extract([pair], "b1", BOUNDS, zone="z1", max_base_ratio=1.0, min_stand=0.0).towers) == 2
    kept = extract([pair], "b1", BOUNDS, zone="z1", max_base_ratio=0.7, min_stand=0.0).towers
    assert len(kept) == 1 and abs(kept.iloc[0]["centroid_x"] - (X0 + 50)) < 1


def test_a_trace_records_what_decided_each_cluster_and_changes_nothing():
    """Every cluster judged is traced with the rule that decided it; the towers are the same."""
    from towerpipe.towers.extract import TRACE_RULES

    xyz, hag = synthetic_tower(X0 + 50, Y0 + 50, seed=1)
    s = np.linspace(0, 1, 60)
    piece = np.column_stack([X0 + 150 + 12 * s, np.full_like(s, Y0 + 50), 124 + 4 * s])
    faint, hf = synthetic_tower(X0 + 300, Y0 + 50, seed=2)
    allxyz = np.concatenate([xyz, piece, faint])
    allhag = np.concatenate([hag, (piece[:, 2] - 100).astype(np.float32), hf])
    prob = np.r_[np.full(len(xyz) + len(piece), 0.95), np.full(len(faint), 0.6)]
    pair = pred_pair(allxyz, allhag, prob, ["b1"])
    trace: list = []
    traced = extract([pair], "b1", BOUNDS, zone="z1", min_core_prob=0.9, processed_at=STAMP, trace=trace).towers
    plain = extract([pair], "b1", BOUNDS, zone="z1", min_core_prob=0.9, processed_at=STAMP).towers
    pd.testing.assert_frame_equal(traced, plain)
    by_x = {round(float(np.median(t["x"])) - X0, -1): t for t in trace}
    assert {t["rule"] for t in trace} <= set(TRACE_RULES)
    assert by_x[50.0]["rule"] == "accepted" and len(by_x[50.0]["x"]) == len(xyz)
    assert by_x[160.0]["rule"] == "floating" and by_x[160.0]["value"] > 0.7
    assert by_x[300.0]["rule"] == "core" and by_x[300.0]["value"] == pytest.approx(0.6)
    assert not any(t["rescue"] for t in trace)


def test_tall_tower_without_conductors_is_dropped_and_support_recorded():
    """With a context, towers >= wire_min_height need a wire pointing at their base."""
    xyz, hag = scene()  # towers 30 m (x0 + 50) and 42 m (x0 + 200)
    pair = pred_pair(xyz, hag, 0.95, ["b1"])
    rng = np.random.default_rng(0)
    s = np.sort(rng.random(600))
    # conductors of the first tower only, running north from it for 300 m
    wires = np.concatenate(
        [
            np.column_stack([np.full(600, X0 + 50 + a), Y0 + 50 + 300 * s, 124 - 5 * np.sin(np.pi * s)])
            for a in (-7.0, 0.0, 7.0)
        ]
    )
    ctx_arrays = {"x": wires[:, 0], "y": wires[:, 1], "z": wires[:, 2], "hag": (wires[:, 2] - 100)}

    def context(cx, cy):
        return ctx_arrays, (X0 - 40, Y0 - 40, X0 + 540, Y0 + 540)

    # the conductor rule alone: the context holds wires only, no object a shape check could judge
    context_rules = {"context": context, "verifier": "none"}

    everything = extract([pair], "b1", BOUNDS, zone="z1", **context_rules, min_wire_support=0.0).towers
    assert len(everything) == 2
    sup = everything.sort_values("centroid_x")["wire_support"].to_numpy()
    assert sup[0] == 1.0 and sup[1] == 0.0
    kept = extract([pair], "b1", BOUNDS, zone="z1", **context_rules, min_wire_support=0.5).towers
    assert len(kept) == 1 and abs(kept.iloc[0]["centroid_x"] - (X0 + 50)) < 1
    # exempt below wire_min_height, and no context means unknown support (NaN), never a drop
    assert (
        len(
            extract([pair], "b1", BOUNDS, zone="z1", **context_rules, min_wire_support=0.5, wire_min_height=50.0).towers
        )
        == 2
    )
    plain = extract([pair], "b1", BOUNDS, zone="z1", min_wire_support=0.5).towers
    assert len(plain) == 2 and plain["wire_support"].isna().all()


def test_members_round_trip_selects_each_blocks_points(tmp_path):
    """The points of reported towers, from any block, go back to their own block's mask."""
    xyz, hag = synthetic_tower(X0 + 499, Y0 + 50, seed=4)  # straddles x = x0 + 500
    east = xyz[:, 0] >= X0 + 500
    pair = pred_pair(xyz, hag, 0.9, ["b1", "b2"], block_id=east.astype(np.int32))
    found = extract([pair], "b1", (X0, Y0, X0 + 500, Y0 + 500), zone="z1")
    found2 = extract([pair], "b2", (X0 + 500, Y0, X0 + 1000, Y0 + 500), zone="z1")
    gdf, members = found.towers, found.members
    gdf2, members2 = found2.towers, found2.members
    assert len(gdf) + len(gdf2) == 1  # reported once
    # but both blocks know its points: each classifies its own part
    tid = (gdf if len(gdf) else gdf2)["tower_id"].iloc[0]
    assert list(members) == list(members2) == [tid]
    path = tmp_path / "m.points.npz"
    save_members(path, members)
    n = len(xyz)
    m1, m2 = member_mask([path], "b1", n), member_mask([path], "b2", n)
    idx = np.arange(n)
    np.testing.assert_array_equal(np.flatnonzero(m1), idx[~east])
    np.testing.assert_array_equal(np.flatnonzero(m2), idx[east])
    assert not member_mask([path], "b3", n).any()
    with pytest.raises(InputError, match="towers_block"):
        member_mask([path], "b1", 10)
    save_members(tmp_path / "empty.npz", {})
    assert not member_mask([tmp_path / "empty.npz"], "b1", n).any()


def test_point_threshold_trims_a_towers_points_not_the_tower():
    """Clustered at `threshold`; n_points and members keep the points at `point_threshold`."""
    xyz, hag = synthetic_tower(X0 + 50, Y0 + 50, seed=6)
    prob = np.where(np.arange(len(xyz)) % 4 == 0, 0.55, 0.95)
    pair = pred_pair(xyz, hag, prob, ["b1"])
    found = extract([pair], "b1", BOUNDS, zone="z1", point_threshold=0.6)
    gdf, members = found.towers, found.members
    assert len(gdf) == 1
    kept = int((prob >= 0.6).sum())
    assert gdf.iloc[0]["n_points"] == kept and len(members[gdf.iloc[0]["tower_id"]][1]) == kept
    full = extract([pair], "b1", BOUNDS, zone="z1").towers
    assert full.iloc[0]["n_points"] == len(xyz)
    assert full.iloc[0]["footprint_area_m2"] == pytest.approx(gdf.iloc[0]["footprint_area_m2"])


def test_towers_found_on_the_single_view_points_chosen_on_the_view_mean():
    """A tower the views disagree on (mean below the cluster threshold) is still found and
    tested on ``prob_single``; its class-15 points are those whose view mean reaches
    ``point_threshold``, and ``prob_mean`` is of the single view."""
    xyz, hag = synthetic_tower(X0 + 50, Y0 + 50, seed=7)
    arrays, meta = pred_pair(xyz, hag, 0.45, ["b1"])  # view mean: every point below 0.5
    crown = np.arange(len(xyz)) % 3 == 0
    arrays["prob"][~crown] = 0.45
    arrays["prob"][crown] = 0.2
    arrays["prob_single"] = np.full(len(xyz), 0.97, np.float32)
    found = extract([(arrays, meta)], "b1", BOUNDS, zone="z1", threshold=0.5, point_threshold=0.4, min_core_prob=0.9)
    gdf, members = found.towers, found.members
    assert len(gdf) == 1
    row = gdf.iloc[0]
    assert row["n_points"] == int((~crown).sum()) and len(members[row["tower_id"]][1]) == row["n_points"]
    assert row["prob_mean"] == pytest.approx(0.97)
    # found on the view mean instead, there would be no tower at all
    mean_only = dict(arrays, prob_single=arrays["prob"])
    assert len(extract([(mean_only, meta)], "b1", BOUNDS, zone="z1", threshold=0.5).towers) == 0


def test_a_tower_reports_at_least_min_points():
    """Clustered from 30 single-view points but only 12 reach the point threshold on the view
    mean: 12 points are not a tower (towers.min_points applies to what is reported)."""
    xyz, hag = synthetic_tower(X0 + 50, Y0 + 50, height=12.0, seed=8)
    xyz, hag = xyz[:30], hag[:30]
    arrays, meta = pred_pair(xyz, hag, 0.3, ["b1"])
    arrays["prob"][:12] = 0.9
    arrays["prob_single"] = np.full(len(xyz), 0.95, np.float32)
    # its 30 points are one splaying leg: no foot rule (tests/towers/test_foot.py) here
    kw = dict(zone="z1", threshold=0.5, min_points=20, min_height=5.0, foot={"height": 0})
    assert len(extract([(arrays, meta)], "b1", BOUNDS, **kw).towers) == 1
    found = extract([(arrays, meta)], "b1", BOUNDS, point_threshold=0.4, **kw)
    assert len(found.towers) == 0 and found.members == {}
    arrays["prob"][:25] = 0.9
    assert len(extract([(arrays, meta)], "b1", BOUNDS, point_threshold=0.4, **kw).towers) == 1


def tower_with_shrubs(cx: float, cy: float, seed: int = 9) -> tuple[np.ndarray, np.ndarray, int]:
    """A lattice tower with a bush between its legs and one beside a leg (within the linkage,
    beyond the outline of its legs above 8 m): xyz, hag and the tower's own point count."""
    xyz, hag = synthetic_tower(cx, cy, seed=seed)
    rng = np.random.default_rng(seed)
    bushes = [
        np.column_stack([cx + rng.normal(0, 0.6, 80), cy + rng.normal(0, 0.6, 80), rng.uniform(100.5, 103, 80)]),
        np.column_stack(
            [cx + 3 + rng.normal(0, 0.3, 60), cy + 4.8 + rng.normal(0, 0.2, 60), rng.uniform(100.5, 103, 60)]
        ),
    ]
    bush = np.concatenate(bushes)
    return np.concatenate([xyz, bush]), np.concatenate([hag, bush[:, 2] - 100.0]), len(xyz)


def test_the_shrubs_at_a_towers_foot_are_not_its_points():
    """Painted with the tower, the bushes between and beside its legs are left out of what is
    reported (towers.foot); the tower and its footprint are as without the rule, and the
    footprint still takes in the bush beside it."""
    xyz, hag, n = tower_with_shrubs(X0 + 50, Y0 + 50)
    pair = pred_pair(xyz, hag, 0.9, ["b1"])
    found = extract([pair], "b1", BOUNDS, zone="z1")
    row = found.towers.iloc[0]
    assert len(found.towers) == 1 and row["n_points"] == n
    assert set(found.members[row["tower_id"]][1].tolist()) == set(range(n))
    bare = extract([pair], "b1", BOUNDS, zone="z1", foot={"height": 0}, crowns={"beyond": 0}).towers.iloc[0]
    assert bare["n_points"] == len(xyz)
    assert bare["footprint_area_m2"] == row["footprint_area_m2"]
    alone = extract([pred_pair(xyz[:n], hag[:n], 0.9, ["b1"])], "b1", BOUNDS, zone="z1").towers.iloc[0]
    assert row["footprint_area_m2"] > alone["footprint_area_m2"] + 1.0


def test_the_foot_and_crown_rules_never_drop_a_tower():
    """A tower that the trimming would leave with fewer than towers.min_points points keeps
    them all: the rules pick points, not towers."""
    xyz, hag, n = tower_with_shrubs(X0 + 50, Y0 + 50)
    pair = pred_pair(xyz, hag, 0.9, ["b1"])
    found = extract([pair], "b1", BOUNDS, zone="z1", min_points=n + 10, crowns={"beyond": 0})
    assert len(found.towers) == 1 and found.towers.iloc[0]["n_points"] == len(xyz)
    # the crown rule alone leaves the bush beside a leg out (towers.crowns), unless too few remain
    crowns = int(extract([pair], "b1", BOUNDS, zone="z1", foot={"height": 0}).towers.iloc[0]["n_points"])
    assert n < crowns < len(xyz)
    found = extract([pair], "b1", BOUNDS, zone="z1", min_points=crowns + 1, foot={"height": 0})
    assert len(found.towers) == 1 and found.towers.iloc[0]["n_points"] == len(xyz)


def test_a_towers_foot_is_judged_alike_by_both_blocks_it_touches():
    """Across a block edge, each block's job trims the tower's foot to the same points,
    whatever the order of the prediction files."""
    edge = X0 + 250.0
    xyz, hag, n = tower_with_shrubs(edge + 0.6, Y0 + 100)
    west = xyz[:, 0] < edge
    pw = pred_pair(xyz[west], hag[west], 0.95, ["bw"], tile="w")
    pe = pred_pair(xyz[~west], hag[~west], 0.95, ["be"], tile="e")
    bw, be = (X0, Y0, edge, Y0 + 500), (edge, Y0, X0 + 500, Y0 + 500)
    a = extract([pw, pe], "bw", bw, zone="z1", processed_at=STAMP).members
    b = extract([pe, pw], "be", be, zone="z1", processed_at=STAMP).members
    assert a.keys() == b.keys() and len(a) == 1
    (tid,) = a

    def points(members):
        blocks, idx = members[tid]
        return sorted(zip(np.asarray(blocks).astype(str).tolist(), np.asarray(idx).tolist(), strict=True))

    assert points(a) == points(b)
    assert len(points(a)) == n
