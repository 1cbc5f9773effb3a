"""The command line of the training (``towerpipe train``)."""

import json

import pytest

from towerpipe.errors import ConfigError
from towerpipe.training.cli import read_overrides


def test_overrides_read_from_yaml_and_json(tmp_path):
    """``--config`` takes the recipe as `config/models.yaml` writes it (YAML) or as JSON."""
    recipe = {"epochs": 16, "segmenter": {"epochs": 20}, "lr_schedule": "onecycle"}
    y = tmp_path / "recipe.yaml"
    y.write_text("epochs: 16\nlr_schedule: onecycle\nsegmenter: {epochs: 20}\n")
    j = tmp_path / "recipe.json"
    j.write_text(json.dumps(recipe))
    assert read_overrides(str(y)) == recipe
    assert read_overrides(str(j)) == recipe
    assert read_overrides(None) == {}


def test_overrides_that_are_not_a_mapping_name_the_file(tmp_path):
    bad = tmp_path / "recipe.yaml"
    bad.write_text("- epochs\n- 16\n")
    with pytest.raises(ConfigError, match="recipe.yaml"):
        read_overrides(str(bad))
