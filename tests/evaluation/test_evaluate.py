"""Zone evaluation helpers: what the false towers of a run are, from the input labels."""

from __future__ import annotations

import json

import geopandas as gpd
import laspy
import numpy as np
import shapely

from towerpipe.evaluation.evaluate import false_tower_sources, hard_negatives, summary_line, zone_points
from towerpipe.synth.truth import META_JSON


def write_block(path, x, y, cls):
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.offsets = [float(np.min(x)), float(np.min(y)), 0.0]
    header.scales = [0.01, 0.01, 0.01]
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, np.zeros(len(x))
    las.classification = cls
    path.parent.mkdir(parents=True, exist_ok=True)
    las.write(path)


def test_false_tower_sources_tally_input_classes(tmp_path):
    rng = np.random.default_rng(0)
    # a crane (input class 1) and a tree (class 5) both called towers, plus a true tower
    crane = rng.normal(0, 0.8, (40, 2)) + [10, 10]
    tree = rng.normal(0, 0.8, (25, 2)) + [60, 60]
    tower = rng.normal(0, 0.8, (30, 2)) + [30, 70]
    ground = rng.uniform(0, 100, (200, 2))
    xy = np.vstack([crane, tree, tower, ground])
    truth = np.r_[np.full(40, 1), np.full(25, 5), np.full(30, 15), np.full(200, 2)].astype(np.uint8)
    pred = np.r_[np.full(40, 15), np.r_[np.full(20, 15), np.full(5, 5)], np.full(30, 15), np.full(200, 2)]
    write_block(tmp_path / "in" / "b.laz", xy[:, 0], xy[:, 1], truth)
    write_block(tmp_path / "res" / "blocks" / "b.laz", xy[:, 0], xy[:, 1], pred.astype(np.uint8))
    false = gpd.GeoDataFrame(
        {"tower_id": ["T_crane", "T_tree"], "height_m": [41.0, 18.0], "n_points": [40, 20], "prob_mean": [0.9, 0.6]},
        geometry=[shapely.box(7, 7, 13, 13), shapely.box(57, 57, 63, 63)],
        crs="EPSG:25831",
    )
    per_block, labelled = zone_points(tmp_path / "in", tmp_path / "res")
    assert per_block == {"b": {"tp": 30, "fp": 60, "fn": 0}}
    rows = false_tower_sources(false, labelled)
    assert [r["tower_id"] for r in rows] == ["T_crane", "T_tree"]
    assert rows[0]["input_classes"] == {1: int(shapely.contains_xy(shapely.box(6.5, 6.5, 13.5, 13.5), *crane.T).sum())}
    assert set(rows[1]["input_classes"]) == {5} and rows[1]["input_classes"][5] <= 20
    assert false_tower_sources(false.iloc[:0], labelled) == []


def test_summary_line_says_n_a_where_a_ratio_is_undefined():
    # a zone where nothing was reported has no precision: the command says so instead of failing
    res = {
        "towers_predicted": 0,
        "towers_true": 1,
        "tower_precision": None,
        "tower_recall": 0.0,
        "towers_reported_twice": 0,
        "point_iou_tower": 0.0,
    }
    assert summary_line(res) == (
        "towers: 0 predicted, 1 true; precision n/a recall 0.000; reported twice 0; point IoU (tower) 0.000"
    )
    assert "precision 0.500 recall 1.000" in summary_line(
        {**res, "towers_predicted": 2, "tower_precision": 0.5, "tower_recall": 1.0}
    )


def test_hard_negatives_counts_the_objects_a_reported_tower_stands_on(tmp_path):
    """The generated zone's recorded cranes and masts by kind, and on how many a reported tower stands."""
    negs = [
        {"kind": "crane", "x": 10.0, "y": 10.0, "height": 40.0},
        {"kind": "crane", "x": 200.0, "y": 10.0, "height": 35.0},
        {"kind": "telecom_mast", "x": 100.0, "y": 100.0, "height": 30.0},
    ]
    (tmp_path / META_JSON).write_text(json.dumps({"seed": 1, "negatives": negs}))
    pred = gpd.GeoDataFrame(
        {"tower_id": ["T1", "T2"]}, geometry=[shapely.box(12, 12, 16, 16), shapely.box(300, 300, 304, 304)]
    )
    assert hard_negatives(tmp_path, pred) == {
        "crane": {"objects": 2, "reported": 1},
        "telecom_mast": {"objects": 1, "reported": 0},
    }
    assert hard_negatives(tmp_path, pred.iloc[:0])["crane"] == {"objects": 2, "reported": 0}
    assert hard_negatives(tmp_path / "real_zone", pred) == {}  # no metadata: a real zone records none


def test_window_figures_refuse_the_tiles_a_model_trained_on(tmp_path, random_model_factory):
    """evaluate-windows on a model's own training tiles gave figures that read as held-out."""
    import shutil

    import pytest

    from towerpipe.errors import InputError
    from towerpipe.evaluation.evaluate import evaluate_windows

    model = tmp_path / "m"
    shutil.copytree(random_model_factory("shape"), model)
    tile = tmp_path / "work" / "z" / "tiles" / "b0" / "0_0.npz"
    tile.parent.mkdir(parents=True)
    tile.write_bytes(b"")  # refused before it is read
    card = json.loads((model / "model_card.json").read_text())
    card.setdefault("training_data", {})["tiles"] = [str(tile)]
    (model / "model_card.json").write_text(json.dumps(card))
    with pytest.raises(InputError, match="1 of the 1 tiles are among those .* was trained on"):
        evaluate_windows(model, [str(tile)])
