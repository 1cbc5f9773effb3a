"""The real-shape benchmark's plumbing: usable recipes per variant, auto rows, report, card stamps."""

from __future__ import annotations

import json

import pytest

from conftest import preprocess_settings, real_tile_zone, schema_config
from towerpipe.evaluation.realshape import run_benchmark, score_resolution, stamp_cards, zone_name

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.shared]


@pytest.fixture(scope="module")
def bare_zone(tmp_path_factory):
    """A tiny benchmark zone: TS40K towers on a real tile, exported without colour, preprocessed."""
    from towerpipe.preprocess import tiling
    from towerpipe.preprocess.split import split_block
    from towerpipe.preprocess.tile import preprocess_tile
    from towerpipe.synth import generate_zone

    tmp = tmp_path_factory.mktemp("realshape")
    zone = zone_name("ts40k", "no_colour")
    truth = generate_zone(
        tmp / "data" / zone, **real_tile_zone(3, "ts40k", (8, 15), "ign_bridge.laz", variant="no_colour")
    )
    block = truth.blocks[0]
    cache = tmp / "work" / zone / "cache" / block["name"]
    settings = preprocess_settings()
    meta = split_block(block["path"], cache, block=block["name"], zone=zone, settings=settings)
    tiling.plan_zone_step(
        {block["name"]: str(cache)},
        str(tmp / "work" / zone / "plan.json"),
        tile_size=settings.tile_size,
        buffer=settings.buffer,
    )
    for t in tiling.tile_ids(tuple(meta["header_bounds"]), settings.tile_size):
        preprocess_tile(
            zone,
            block["name"],
            t,
            {block["name"]: cache},
            tmp / "work" / zone / "tiles" / block["name"] / f"{t}.npz",
            settings=settings,
        )
    return tmp, zone, truth


def test_benchmark_rows_auto_and_report(bare_zone, random_model_factory):
    tmp, zone, truth = bare_zone
    assert len(truth.towers) >= 1
    loso = {"full": {"ts40k": random_model_factory("full")}, "shape": {"ts40k": random_model_factory("shape")}}
    # the schema's defaults, with a lenient gate and tower rules (random models)
    cfg = schema_config(
        inference={"gate": 0.5, "batch_size": 8, "tta": 1, "windows": "grid", "threshold": 0.5},
        towers={
            "threshold": 0.5,
            "min_core_prob": 0.0,
            "min_wire_support": 0.0,
            "wire_line_coverage": 0.0,
            "max_base_ratio": 1.0,
            "min_shape_score": 0.0,
            "split_thresholds": [],
        },
    )
    inference, towers = cfg["inference"], cfg["towers"]
    out = tmp / "out"
    result = run_benchmark(
        loso, {zone: tmp / "data" / zone}, work=tmp / "work", inference=inference, towers=towers, out_dir=out
    )
    rows = {r["recipe"]: r for r in result["rows"]}
    # no colour in this variant: the full recipe cannot run, the shape recipe can
    assert not rows["full"]["usable"] and rows["full"]["missing"] == ["nir", "rgb"]
    assert rows["shape"]["usable"] and rows["shape"]["true_towers"] == len(truth.towers)
    # a share of the true towers: how many of them a window passing the gate reached
    reached = rows["shape"]["gate_recall"] * len(truth.towers)
    assert 0 <= round(reached) <= len(truth.towers) and reached == pytest.approx(round(reached))
    assert [a["feature_set"] for a in result["auto"]] == ["shape"]
    report = (out / "report.md").read_text()
    assert "not usable: no valid nir, rgb" in report and "| ts40k | no_colour | shape |" in report
    assert json.loads((out / "scores.json").read_text())["transfer"]["full"]["score"] is None


def test_benchmark_judges_conductor_support_where_the_pipeline_does(bare_zone, random_model_factory, monkeypatch):
    """The benchmark scores a zone with the measured bounds of its blocks, as the towers jobs do:
    a tower whose conductor ring lies mostly outside the data keeps an unknown support
    (``towers.wire_line_coverage``) instead of being judged on the rest of its ring."""
    import towerpipe.evaluation.calibrate as calibrate
    from towerpipe.evaluation.calibrate import zone_survey

    tmp, zone, truth = bare_zone
    seen = []
    score_zone = calibrate.score_zone

    def spy(*args, **kw):
        seen.append(kw["survey"])
        return score_zone(*args, **kw)

    monkeypatch.setattr(calibrate, "score_zone", spy)
    cfg = schema_config(inference={"tta": 1, "windows": "grid", "batch_size": 8})
    run_benchmark(
        {"shape": {"ts40k": random_model_factory("shape")}},
        {zone: tmp / "data" / zone},
        work=tmp / "work",
        inference=cfg["inference"],
        towers=cfg["towers"],
        out_dir=tmp / "out_survey",
    )
    survey = zone_survey(tmp / "work", zone)
    assert len(survey) == len(truth.blocks)  # one measured box per block
    assert seen and all(s == survey for s in seen)


def test_stamp_cards_writes_the_transfer_figures(tmp_path, random_model_factory):
    import shutil

    from towerpipe.model.cards import read_card

    model = tmp_path / "m"
    shutil.copytree(random_model_factory("shape"), model)
    scores = tmp_path / "scores.json"
    scores.write_text(
        json.dumps(
            {
                "transfer": {"shape": {"score": 0.93, "point_iou": 0.71, "families": ["uav"], "resolution": 0.08}},
                "rows": [
                    {
                        "recipe": "shape",
                        "usable": True,
                        "family": "uav",
                        "variant": "intact",
                        "gate_recall": 1.0,
                        "recall": 0.95,
                        "precision": 0.9,
                        "point_iou": 0.7,
                    }
                ],
            }
        )
    )
    stamp_cards(scores, {"shape": model})
    card = read_card(model)  # the weights' checksums still hold
    assert card["transfer"]["score"] == 0.93 and card["transfer"]["per_family"][0]["recall"] == 0.95
    assert card["transfer"]["resolution"] == 0.08
    assert "## Transfer" in (model / "MODEL_CARD.md").read_text()
    assert card["transfer"]["spread"] == 0.0 and len(card["transfer"]["runs"]) == 1


def _scores(path, score, recall):
    path.write_text(
        json.dumps(
            {
                "transfer": {"shape": {"score": score, "point_iou": 0.6, "families": ["uav"], "resolution": 0.01}},
                "rows": [{"recipe": "shape", "usable": True, "family": "uav", "variant": "intact", "recall": recall}],
            }
        )
    )
    return path


def test_stamp_cards_adds_a_training_to_the_earlier_runs(tmp_path, random_model_factory):
    """``--add``: the mean of the runs' scores and their spread (a tie margin of ``auto``); the
    per-family rows of the latest; a card stamped before runs were kept counts as one run; without
    it a run replaces them all."""
    import shutil

    from towerpipe.model.cards import read_card, write_card
    from towerpipe.model.choice import transfer_resolution

    model = tmp_path / "m"
    shutil.copytree(random_model_factory("shape"), model)
    card = read_card(model)
    card["transfer"] = {"score": 0.9, "point_iou": 0.8, "resolution": 0.01, "per_family": [], "families": ["uav"]}
    write_card(model, card)  # as stamped before runs were kept
    stamp_cards(_scores(tmp_path / "a.json", 0.8, 0.75), {"shape": model}, add=True)
    t = read_card(model)["transfer"]
    assert [r["score"] for r in t["runs"]] == [0.9, 0.8] and t["score"] == pytest.approx(0.85)
    assert t["spread"] == pytest.approx(0.1) and t["point_iou"] == pytest.approx(0.7)
    assert t["per_family"][0]["recall"] == 0.75
    assert transfer_resolution({"transfer": t}) == pytest.approx(0.1)  # the spread, larger than a tower
    stamp_cards(_scores(tmp_path / "b.json", 0.87, 0.8), {"shape": model}, add=True)
    t = read_card(model)["transfer"]
    assert (
        len(t["runs"]) == 3
        and t["score"] == pytest.approx((0.9 + 0.8 + 0.87) / 3)
        and t["spread"] == pytest.approx(0.1)
    )
    stamp_cards(_scores(tmp_path / "c.json", 0.7, 0.5), {"shape": model})
    t = read_card(model)["transfer"]
    assert [r["score"] for r in t["runs"]] == [0.7] and t["spread"] == 0.0


@pytest.mark.parametrize(
    ("sizes", "expected"),
    [([(19, 0), (11, 1), (5, 4)], 1 / (19 * 3)), ([(3, 9)], 1 / 12), ([(0, 0)], None), ([], None)],
)
def test_score_resolution_is_one_tower_of_the_largest_family(sizes, expected):
    rows = [{"towers_tp": tp, "towers_fn": fn} for tp, fn in sizes]
    assert score_resolution(rows) == (pytest.approx(expected) if expected else None)
