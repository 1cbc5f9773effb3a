"""Tests of towerpipe.evaluation.trace: the table of where each true tower was lost, and its
errors (the stages themselves: tests/workflow/test_e2e.py on the CI scene, tests/towers for the trace)."""

from __future__ import annotations

import pytest

from towerpipe.errors import InputError
from towerpipe.evaluation.trace import (
    GATE_STAGES,
    MERGED,
    RULE_NAMES,
    STAGE_NAMES,
    _gate_stage,
    _merged_with,
    _reported,
    trace_table,
    trace_zone,
)
from towerpipe.towers.extract import TRACE_RULES


def _row(tid: str, stage: str, value: float = float("nan"), cluster: int = 0) -> dict:
    return {
        "tower_id": tid,
        "design": "small_lattice",
        "height_m": 16.5,
        "n_points": 180,
        "max_prob": 0.24,
        "stage": stage,
        "value": value,
        "cluster_points": cluster,
    }


def test_every_rule_of_a_trace_has_a_reading():
    assert set(RULE_NAMES) == set(TRACE_RULES)


def test_the_table_lists_the_missed_towers_first_and_counts_the_found():
    rows = [_row("2", "found"), _row("10", "core", 0.24, 105), _row("9", "not segmented")]
    lines = trace_table(rows).splitlines()
    body = [line for line in lines if line.startswith("| ") and not line.startswith("| tower")]
    assert [line.split("|")[1].strip() for line in body] == ["9", "10", "2"]
    assert RULE_NAMES["core"] in body[1] and "0.240" in body[1] and "| 105 |" in body[1]
    assert lines[-1] == "1 of 3 true towers found."


def test_a_tower_never_segmented_is_told_which_gate_refused_it():
    """The windows centred on a tower's footprint (buffered) and the gates' record of them
    (``window_gates`` of the inference) name the gate that lost it, with its best score."""
    import numpy as np
    import shapely

    near = shapely.box(0, 0, 4, 4)
    gates = {
        "x": np.array([2.0, 3.0, 50.0]),
        "y": np.array([2.0, 1.0, 50.0]),
        "shape": np.array([0.001, 0.002, 0.9]),
        "prob": np.array([np.nan, np.nan, 0.8]),
        "gate": 0.03,
    }
    assert _gate_stage(near, gates) == ("shape gate", 0.002)
    gates["shape"][1], gates["prob"][1] = 0.5, 0.02
    assert _gate_stage(near, gates) == ("classifier gate", 0.02)
    gates["prob"][1] = 0.4  # passed both gates, not segmented all the same: no gate lost it
    assert _gate_stage(near, gates) == ("not segmented", 0.4)
    # passed the classifier's gate unsure (under gate_sure) with a peak object under unsure_shape
    gates.update(gate_sure=0.5, unsure_shape=0.6)
    assert _gate_stage(near, gates) == ("unsure gate", 0.4)
    gates["shape"][1] = 0.7
    assert _gate_stage(near, gates) == ("not segmented", 0.4)
    assert _gate_stage(shapely.box(100, 100, 104, 104), gates) == (
        "no window",
        pytest.approx(float("nan"), nan_ok=True),
    )
    assert _gate_stage(near, None)[0] == "not segmented"  # predictions written before the record
    rows = [_row("3", "shape gate", 0.002), _row("4", "no window")]
    table = trace_table(rows)
    assert GATE_STAGES["shape gate"] in table and "0.002" in table and GATE_STAGES["no window"] in table


def test_a_tower_reported_as_one_with_the_tower_beside_it_is_told_so():
    """A true tower whose accepted cluster also holds another true tower, which the report matched (two
    lines side by side), is ``merged``, at the distance between the two; a cluster holding no other
    matched tower leaves it ``accepted`` (reported more than 5 m away)."""
    import geopandas as gpd
    import numpy as np
    import shapely

    truth = gpd.GeoDataFrame(
        {"tower_id": ["1", "2", "3"]},
        geometry=[shapely.box(0, 0, 4, 4), shapely.box(12, 0, 16, 4), shapely.box(100, 0, 104, 4)],
    )
    xs, ys = np.meshgrid(np.arange(0.0, 16.5, 0.5), np.arange(0.0, 4.5, 0.5))  # one cluster over 1 and 2
    entry = {"x": xs.ravel(), "y": ys.ravel()}
    assert _merged_with(entry, truth.geometry[0], truth, {"2": 5}) == 12.0
    assert np.isnan(_merged_with(entry, truth.geometry[0], truth, {"3": 5}))  # 3 matched, not in the cluster
    assert np.isnan(_merged_with(entry, truth.geometry[0], truth, {}))  # 2 in it, but not reported
    assert np.isnan(_merged_with({"x": xs.ravel()[:20], "y": ys.ravel()[:20]}, truth.geometry[0], truth, {"2": 5}))
    assert MERGED in STAGE_NAMES and MERGED not in RULE_NAMES  # a reading of the match, not a rule
    table = trace_table([_row("1", MERGED, 12.0, 900)])
    assert STAGE_NAMES[MERGED] in table and "12.000" in table


def test_a_zone_never_run_names_the_run_to_do(tmp_path):
    with pytest.raises(InputError, match=r"snakemake --cores 2 results/z1/"):
        trace_zone(tmp_path, "z1", tmp_path, inference={"threshold": 0.3}, towers={})


def test_a_found_tower_counts_the_points_it_reports_that_are_no_tower():
    """Crowns painted with a found tower: its reported points across blocks, and those of them the
    input does not label 15; the table shows both for found towers only."""
    import numpy as np

    members = {7: (np.array(["b1", "b1", "b1", "b2", "b2"]), np.array([3, 4, 9, 0, 5]))}
    labels = {"b1": np.array([3, 4, 5]), "b2": np.array([0])}
    assert _reported(members, "7", labels) == {"reported_points": 5, "reported_other": 2}
    assert _reported(members, "8", labels) == {"reported_points": 0, "reported_other": 0}
    found = {**_row("2", "found"), "reported_points": 5, "reported_other": 2}
    lines = trace_table([found, _row("10", "core", 0.24, 105)]).splitlines()
    assert lines[0].endswith("| reported points | of them not tower |")
    assert lines[3].endswith("| 5 | 2 |") and lines[2].endswith("| 105 |  |  |")


@pytest.mark.parametrize("model", [None, "models/towerpipe-geometry-v3"])
def test_cached_traces_the_predictions_calibrate_scores(tmp_path, monkeypatch, model):
    """``towerpipe trace --cached`` traces the calibration cache's predictions of the zone (today's
    inference, the config's settings; the zone's own model choice unless ``--model``), not its last run."""
    import towerpipe.evaluation.calibrate as calibrate
    import towerpipe.evaluation.predcache as predcache
    import towerpipe.evaluation.trace as trace
    from towerpipe.cli import main

    cfg = tmp_path / "zone.yaml"
    cfg.write_text(f"workdir: {tmp_path / 'work'}\nzones:\n  z1: {{input: {tmp_path / 'in'}}}\n")
    asked = {}
    monkeypatch.setattr(calibrate, "zone_model", lambda work, zone, spec: f"chosen-for-{zone}-{spec}")

    def cache(work, zone, model, settings, verifier):
        asked.update(zone=zone, model=model, tta=settings.tta, verifier=verifier)
        return ["cached.npz"]

    monkeypatch.setattr(predcache, "zone_predictions", cache)
    monkeypatch.setattr(trace, "trace_zone", lambda *a, predictions=None, **kw: asked.update(preds=predictions) or [])
    argv = ["trace", "--zone", "z1", "--config", str(cfg), "--cached"] + (["--model", model] if model else [])
    assert main(argv) == 0
    assert asked["preds"] == ["cached.npz"] and asked["zone"] == "z1" and asked["verifier"] == "shipped"
    assert asked["model"] == (model or "chosen-for-z1-auto")
    asked.clear()
    assert main(["trace", "--zone", "z1", "--config", str(cfg)]) == 0
    assert asked == {"preds": None}  # the zone's last run
