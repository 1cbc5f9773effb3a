"""Real airborne tiles run exactly as a user runs them: a zone with `input` only, every other setting
at its default (``inference.model: auto``).

The corridor zone is a public-derivative-like re-export of a real IGN tile (RGB kept, NIR all 0,
intensity, return numbers, scan angle and GPS time all 0) with real lattice towers on lines with
conductors. The background zone is the real IGN tiles as delivered, which hold no pylon.
"""

from __future__ import annotations

import json
import shutil

import pyogrio
import pytest

from conftest import BACKGROUNDS, REPO, real_tile_zone, snakemake_run, write_zone_config
from towerpipe.towers.shape import VERIFIER_RELEASE

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow, pytest.mark.shared]

ZONE = "realdata_corridor"


def run_zones(cfg, zones):
    """``snakemake --cores 2 results/<zone>/ ...`` with the zones' config file, as a user runs it."""
    proc = snakemake_run("--cores", "2", *(f"results/{z}/" for z in zones), f"--configfile={cfg}")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]


@pytest.fixture(scope="module")
def corridor(tmp_path_factory):
    from towerpipe.synth import generate_zone

    tmp = tmp_path_factory.mktemp("corridor")
    truth = generate_zone(
        tmp / "in",
        **real_tile_zone(
            77,
            ["uav", "ts40k"],
            (10, 20),
            "ign_rgb_subset.laz",
            copies=3,
            tower_variety=True,
            variant=["no_intensity", "no_nir"],
        ),
    )
    run_zones(write_zone_config(tmp / "zones.yaml", {ZONE: {"input": str(tmp / "in")}}, tmp / "work"), [ZONE])
    yield tmp, truth, REPO / "results" / ZONE
    shutil.rmtree(REPO / "results" / ZONE, ignore_errors=True)


def test_attributes_recorded_and_a_usable_model_chosen(corridor):
    tmp, _, out = corridor
    choice = json.loads((tmp / "work" / ZONE / "model.json").read_text())
    assert choice["mode"] == "auto" and choice["key"] == "inference.model"
    assert choice["valid_attributes"] == ["rgb"]
    assert choice["feature_set"] == "shape" and "transfers best" in choice["reason"]
    # each block's preprocessing summary, as its QA page records it
    pages = [p for p in (out / "qa").glob("*.json") if p.name != "index.json"]
    assert pages
    for page in pages:
        assert json.loads(page.read_text())["stats"]["degenerate_attributes"] == ["intensity", "returns", "nir"]


def test_towers_found_and_named_with_the_model(corridor):
    from towerpipe.evaluation.evaluate import evaluate_zone

    tmp, truth, out = corridor
    rep = evaluate_zone(tmp / "in", out)
    assert rep["towers_true"] == len(truth.towers) >= 3
    assert rep["tower_recall"] == 1.0, rep
    meta = pyogrio.read_info(out / "towers.gpkg", layer="towers")["dataset_metadata"]
    choice = json.loads(meta["model_choice"])
    assert choice["mode"] == "auto" and choice["reason"].startswith("auto:")
    assert meta["model_verifier"] == f"towerpipe-verifier-v{VERIFIER_RELEASE}"  # the shape check's


def test_tower_points_outlined(corridor):
    """The towers' points, against the labels: point IoU at the real-towers bar (0.70). The
    low vegetation at a tower's foot, which the segmenter paints with it, is left out
    (towers.foot; 0.64 without)."""
    from towerpipe.evaluation.evaluate import evaluate_zone

    tmp, _, out = corridor
    rep = evaluate_zone(tmp / "in", out)
    assert rep["point_iou_tower"] >= 0.70, rep["points"]


def test_no_tree_reported(corridor):
    """The real trees of 10-11 m beside the line (class 1 in this tile), which the segmenter paints
    as tower points, are held back by the shape check (towers.min_shape_score)."""
    from towerpipe.evaluation.evaluate import evaluate_zone

    tmp, _, out = corridor
    rep = evaluate_zone(tmp / "in", out)
    assert rep["tower_precision"] == 1.0, rep["false_towers"]


def test_real_tiles_without_a_pylon_report_no_tower(tmp_path):
    """The five real IGN tiles of ``../shared`` as delivered (none holds a pylon; trees, roofs, a
    bridge, noise 1,360 m up, an all-zero NIR, point formats 6 and 8), one zone with its ``input``
    only, as the config's ``realbg`` zone: no tower in its GeoPackage, no point classified as tower,
    and a QA index that says so."""
    import laspy
    import numpy as np

    from towerpipe import classes

    zone = "realdata_backgrounds"
    cfg = write_zone_config(tmp_path / "zones.yaml", {zone: {"input": str(BACKGROUNDS)}}, tmp_path / "work")
    out = REPO / "results" / zone
    try:
        run_zones(cfg, [zone])
        assert len(pyogrio.read_dataframe(out / "towers.gpkg", layer="towers")) == 0
        blocks = sorted((out / "blocks").glob("*.laz"))
        assert [b.stem for b in blocks] == sorted(t.stem for t in BACKGROUNDS.glob("*.laz"))
        for block in blocks:
            assert not np.isin(laspy.read(block).classification, classes.TOWER).any(), block
        totals = json.loads((out / "qa" / "index.json").read_text())["totals"]
        assert totals["towers"] == 0 and totals["failed"] == 0, totals
    finally:
        shutil.rmtree(out, ignore_errors=True)
