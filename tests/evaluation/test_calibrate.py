"""towerpipe.evaluation.calibrate: the error paths and the key of the cached predictions (the sweep
itself is checked against the pipeline on the CI zone in test_e2e.py)."""

from __future__ import annotations

import pytest

from conftest import inference_settings
from towerpipe.cli import main
from towerpipe.errors import InputError
from towerpipe.evaluation.calibrate import sweep, zone_predictions


def test_a_zone_without_tiles_names_the_command_to_run(tmp_path):
    with pytest.raises(InputError, match=r"snakemake --cores 2 results/calib9/"):
        zone_predictions(tmp_path, "calib9", "models/x", inference_settings(tta=2))


def test_a_zone_without_truth_cannot_be_calibrated(tmp_path):
    with pytest.raises(InputError, match="towers_truth.gpkg"):
        sweep({"z": tmp_path}, [(1, 0.5, 0.5, 0.9)], work=str(tmp_path), model="m", inference={}, towers={})


def test_cli_rejects_an_undefined_zone(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("zones: {a: {input: data/a}}\n")
    assert main(["calibrate", "--config", str(cfg), "--zones", "nope"]) != 0
    assert "nope" in capsys.readouterr().err


def test_the_prediction_cache_key_covers_the_tower_code_the_inference_runs():
    """The cached predictions are keyed by the code that makes them (INFERENCE_PACKAGES). The
    inference runs two modules of the tower code, the wire detector (overhead wires left out of
    the peaks) and the shape module (the shape gate cuts and scores each peak's object): a change
    to either must predict the zones again. Every ``towerpipe.towers`` module that the inference
    or the model code imports is in the key."""
    import ast

    from conftest import REPO
    from towerpipe.evaluation.calibrate import INFERENCE_PACKAGES

    src = REPO / "src" / "towerpipe"
    imported = set()
    for path in [*(src / "inference").rglob("*.py"), *(src / "model").rglob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("towerpipe.towers"):
                imported.add(node.module)
            elif isinstance(node, ast.Import):
                imported |= {a.name for a in node.names if a.name.startswith("towerpipe.towers")}
    assert imported >= {"towerpipe.towers.shape", "towerpipe.towers.wires"}
    uncovered = {m for m in imported if not any(m == p or m.startswith(p + ".") for p in INFERENCE_PACKAGES)}
    assert not uncovered, f"modules the inference runs but the prediction cache ignores: {sorted(uncovered)}"
