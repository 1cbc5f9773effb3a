"""towerpipe.evaluation.calibrate: the error paths (the sweep itself is checked against the pipeline
on the CI zone in test_e2e.py)."""

from __future__ import annotations

import pytest

from towerpipe.cli import main
from towerpipe.errors import InputError
from towerpipe.evaluation.calibrate import sweep


def test_a_zone_without_truth_cannot_be_calibrated(tmp_path):
    with pytest.raises(InputError, match="towers_truth.gpkg"):
        sweep({"z": tmp_path}, [(1, 0.5, 0.5, 0.9)], work=str(tmp_path), model="m", inference={}, towers={})


def test_cli_rejects_an_undefined_zone(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("zones: {a: {input: data/a}}\n")
    assert main(["calibrate", "--config", str(cfg), "--zones", "nope"]) != 0
    assert "nope" in capsys.readouterr().err
