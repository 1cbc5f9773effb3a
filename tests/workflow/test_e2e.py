"""End to end on the CI zone (.test/config): raw blocks in -> classified blocks, towers, QA out.

Uses the model ``inference.model: auto`` chooses for the zone, and checks that it reproduces
the metrics recorded in its model card on this (deterministically generated) zone.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pyogrio
import pytest

from conftest import REPO
from towerpipe.config import effective_config

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]

ZONE = "ci"


@pytest.fixture(scope="module")
def zone_run(tmp_path_factory):
    work = tmp_path_factory.mktemp("work")
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "--cores",
        "2",
        f"results/{ZONE}/",
        "--configfile=.test/config/config.yaml",
        "--config",
        f"workdir={work}",
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    yield REPO / "results" / ZONE, REPO / "data" / ZONE, cmd
    # (the chosen model: work/<zone>/model.json, written by the choose_model checkpoint)
    shutil.rmtree(REPO / "results" / ZONE, ignore_errors=True)


def chosen_model(cmd) -> str:
    """The model directory the zone's choose_model checkpoint picked."""
    from towerpipe.model.choice import read_choice

    work = next(a.split("=", 1)[1] for a in cmd if a.startswith("workdir="))
    return read_choice(Path(work) / ZONE / "model.json")["path"]


def test_every_point_and_attribute_survives(zone_run):
    out, data, _ = zone_run
    inputs = sorted(data.glob("*.laz"))
    assert inputs
    threshold = effective_config(root=REPO)["inference"]["threshold"]
    towers = pyogrio.read_dataframe(out / "towers.gpkg", layer="towers")
    n15 = 0
    for src in inputs:
        a = laspy.read(src)
        b = laspy.read(out / "blocks" / src.name)
        assert len(b.points) == len(a.points)
        assert b.header.parse_crs() == a.header.parse_crs()
        assert "TowerProbability" in b.point_format.dimension_names
        for dim in a.point_format.dimension_names:
            if dim != "classification":
                np.testing.assert_array_equal(np.asarray(b[dim]), np.asarray(a[dim]), err_msg=f"{src.name}: {dim}")
        cls_in, cls_out = np.asarray(a.classification), np.asarray(b.classification)
        changed = cls_in != cls_out
        assert set(np.unique(cls_out[changed])) <= {1, 15}, "only tower labels change"
        prob = np.asarray(b["TowerProbability"])
        # 15 = the points of the reported towers: all of them at or above the point threshold
        assert (prob[cls_out == 15] >= threshold).all()
        n15 += int((cls_out == 15).sum())
    assert n15 == int(towers["n_points"].sum()) > 0


def test_geopackage_and_qa(zone_run):
    out, _, _ = zone_run
    layers = dict(pyogrio.list_layers(out / "towers.gpkg"))
    assert layers.get("towers") == "Polygon" and layers.get("tower_points") == "Point"
    info = pyogrio.read_info(out / "towers.gpkg", layer="towers")
    assert "25831" in info["crs"]
    index = (out / "qa" / "index.html").read_text()
    # the index links every block's page and the zone's GeoPackage, counts the zone's towers and
    # draws its map
    blocks = sorted(p.stem for p in (out / "blocks").glob("*.laz"))
    assert blocks and all(f'href="{b}.html"' in index for b in blocks)
    assert 'href="../towers.gpkg"' in index and "<svg" in index
    n_towers = info["features"]
    assert n_towers > 1 and f"{n_towers} towers found in {len(blocks)} blocks" in index
    for page in (out / "qa").glob("*.html"):
        assert "http://" not in page.read_text() and "https://" not in page.read_text()


def test_shipped_model_reproduces_its_recorded_metrics(zone_run):
    from towerpipe.evaluation.evaluate import evaluate_zone

    out, data, cmd = zone_run
    card = json.loads((Path(chosen_model(cmd)) / "model_card.json").read_text())
    ref = card["metrics"]["reference_zone"]
    assert ref["zone_config"] == ".test/config/config.yaml"
    res = evaluate_zone(data, out)
    assert res["towers_true"] == ref["towers_true"]
    for key in ("tower_precision", "tower_recall", "point_iou_tower"):
        assert res[key] == pytest.approx(ref[key], abs=0.05), key
    assert res["towers_reported_twice"] == 0


def test_calibration_sweep_reproduces_the_pipeline(zone_run):
    """`towerpipe calibrate` builds the towers of the whole zone at once from cached
    predictions; for the configured candidate its figures are the pipeline's."""
    from towerpipe.evaluation.calibrate import sweep
    from towerpipe.evaluation.evaluate import evaluate_zone

    out, data, cmd = zone_run
    work = next(a.split("=", 1)[1] for a in cmd if a.startswith("workdir="))
    cfg = effective_config(root=REPO)
    inf, tow = cfg["inference"], cfg["towers"]
    configured = (inf["tta"], tow["threshold"], inf["threshold"], tow["min_core_prob"])
    rows = sweep(
        {ZONE: data},
        [configured, (1, tow["threshold"], 0.6, tow["min_core_prob"])],
        work=work,
        model=chosen_model(cmd),
        inference=inf,
        towers=tow,
    )
    res = evaluate_zone(data, out)
    got = rows[0][ZONE]
    assert got["towers"] == res["towers_predicted"]
    assert got["precision"] == pytest.approx(res["tower_precision"])
    assert got["recall"] == pytest.approx(res["tower_recall"])
    assert (got["tp"], got["fp"], got["fn"]) == tuple(res["points"][k] for k in ("tp", "fp", "fn"))
    # the zone's totals, and its true towers of towers.min_points points or more as the evaluation counts them
    assert [rows[0][f"total_{k}"] for k in ("towers_tp", "towers_fp", "true_towers")] == [
        got["towers_tp"],
        got["towers_fp"],
        got["true_towers"],
    ]
    big = evaluate_zone(data, out, min_truth_points=tow["min_points"])
    assert got["true_towers_min_points"] == big["towers_true"] <= got["true_towers"]
    assert got["towers_tp_min_points"] == round(big["tower_recall"] * big["towers_true"]) <= got["towers_tp"]
    # one view: the predictions are computed (and cached) for it, the same towers are found
    one = rows[1][ZONE]
    assert one["towers"] == got["towers"] and one["tp"] + one["fn"] == got["tp"] + got["fn"]
    assert rows[1]["mean_point_iou"] == pytest.approx(one["point_iou"])
    assert len(list((Path(work) / ZONE / "calibrate").glob("*/*.npz"))) == 2 * len(
        list((Path(work) / ZONE / "tiles").glob("*/*.npz"))
    )


def test_snakemake_report_holds_the_qa_pages(zone_run, tmp_path):
    report = tmp_path / "report.zip"
    proc = subprocess.run(zone_run[2] + ["--report", str(report)], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    import zipfile

    with zipfile.ZipFile(report) as z:
        names = z.namelist()
        qa = [n for n in names if n.endswith(".html") and not n.endswith("report.html")]
        blocks = {p.stem for p in (REPO / "results" / ZONE / "blocks").glob("*.laz")}
        assert {n.rsplit("/", 1)[-1][:-5] for n in qa} >= blocks, names
        page = z.read(next(n for n in qa if n.rsplit("/", 1)[-1][:-5] in blocks)).decode()
        assert "data:image/png;base64," in page  # the QA plots are embedded in the report's pages
        # the zone's QA index and GeoPackage are in the report too
        assert any(n.endswith("qa/index.html") for n in qa) and any(n.endswith("towers.gpkg") for n in names)
        assert any(n.endswith("report.html") for n in names)


def test_trace_tells_found_from_missed_as_the_scores_do(zone_run):
    """`towerpipe trace` runs the tower rules again on the zone's own predictions: the towers
    it finds are those the pipeline reported, and each missed one is given the stage that lost it."""
    from towerpipe.evaluation.evaluate import evaluate_zone
    from towerpipe.evaluation.trace import GATE_STAGES, RULE_NAMES, trace_table, trace_zone

    out, data, cmd = zone_run
    work = next(a.split("=", 1)[1] for a in cmd if a.startswith("workdir="))
    cfg = effective_config([REPO / ".test/config/config.yaml"], root=REPO)
    rows = trace_zone(work, ZONE, data, inference=cfg["inference"], towers=cfg["towers"])
    res = evaluate_zone(data, out)
    small = sum(n < cfg["towers"]["min_points"] for n in pyogrio.read_dataframe(data / "towers_truth.gpkg")["n_points"])
    assert len(rows) == res["towers_true"] - small
    found = [r for r in rows if r["stage"] == "found"]
    assert len(found) == round(res["tower_recall"] * res["towers_true"])
    stages = {"found", "not segmented", "faint", "no cluster", *RULE_NAMES, *GATE_STAGES}
    assert all(r["stage"] in stages for r in rows)
    for r in rows:
        if r["stage"] in RULE_NAMES:
            assert r["cluster_points"] > 0
    assert all(0 <= r["reported_other"] < r["reported_points"] for r in found)
    table = trace_table(rows)
    assert table.splitlines()[-1] == f"{len(found)} of {len(rows)} true towers found."
