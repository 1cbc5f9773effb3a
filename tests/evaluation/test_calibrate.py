"""towerpipe.evaluation.calibrate: the error paths (the sweep itself is checked against the pipeline
on the CI zone in test_e2e.py)."""

from __future__ import annotations

import pytest

from towerpipe.cli import main
from towerpipe.errors import InputError
from towerpipe.evaluation.calibrate import sweep, sweep_table


def test_a_zone_without_truth_cannot_be_calibrated(tmp_path):
    with pytest.raises(InputError, match="towers_truth.gpkg"):
        sweep({"z": tmp_path}, [(1, 0.5, 0.5, 0.9)], work=str(tmp_path), model="m", inference={}, towers={})


def test_cli_rejects_an_undefined_zone(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("zones: {a: {input: data/a}}\n")
    assert main(["calibrate", "--config", str(cfg), "--zones", "nope"]) != 0
    assert "nope" in capsys.readouterr().err


def test_the_table_prints_each_setting_with_the_decimals_it_has():
    """A gate of 0.005 and one of 0.01 are two rows that must not read alike."""
    zone = {"precision": 1.0, "recall": None, "point_iou": 0.7718}
    common = {"tta": 2, "threshold": 0.3, "point_threshold": 0.3, "min_core_prob": 0.3, "min_wire_support": 0.5}
    common.update(
        total_towers_tp=350,
        total_true_towers=424,
        total_towers_tp_min_points=341,
        total_true_towers_min_points=383,
        total_towers_fp=6,
    )
    rows = [
        {**common, "gate": g, "rescue_threshold": 0.1, "z": zone, "mean_f1": 0.9014, "mean_point_iou": 0.7718}
        for g in (0.005, 0.01)
    ]
    header, a, b = sweep_table(rows, ["z"])
    assert header.startswith("views  gate") and "z: P / R / IoU" in header
    assert " 0.005 " in a and " 0.01 " in b and " 0.005 " not in b
    assert "1.000 /   -   / 0.7718" in a and "| 0.9014 | 0.7718 |" in a
    # the towers found of all true towers, of those of towers.min_points points or more, and the false ones
    assert header.endswith("| found / true (of min_points or more) / false")
    assert a.endswith("| 350 / 424 (341 / 383) / 6")


def test_a_false_tower_is_reported_with_where_it_stands():
    import geopandas as gpd
    import shapely

    from towerpipe.evaluation.calibrate import false_tower_rows

    false = gpd.GeoDataFrame(
        {"height_m": [9.34], "n_points": [23]}, geometry=[shapely.box(487951.0, 6632655.0, 487953.6, 6632657.2)]
    )
    assert false_tower_rows(false) == [{"height_m": 9.3, "n_points": 23, "x": 487952.3, "y": 6632656.1}]
    assert false_tower_rows(false.iloc[:0]) == []
