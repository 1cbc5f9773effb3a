"""towerpipe.evaluation.predcache: the key of a zone's cached predictions, and the error of a zone
without tiles."""

from __future__ import annotations

import pytest

from conftest import inference_settings
from towerpipe.errors import InputError
from towerpipe.evaluation.predcache import zone_predictions


def test_a_zone_without_tiles_names_the_command_to_run(tmp_path):
    with pytest.raises(InputError, match=r"snakemake --cores 2 results/calib9/"):
        zone_predictions(tmp_path, "calib9", "models/x", inference_settings(tta=2))


def test_the_prediction_cache_key_covers_the_tower_code_the_inference_runs():
    """The cached predictions are keyed by the code that makes them (INFERENCE_PACKAGES). The
    inference runs two modules of the tower code, the wire detector (overhead wires left out of
    the peaks) and the shape module (the shape gate cuts and scores each peak's object): a change
    to either must predict the zones again. Every ``towerpipe.towers`` module that the inference
    or the model code imports is in the key."""
    import ast

    from conftest import REPO
    from towerpipe.evaluation.predcache import INFERENCE_PACKAGES

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


def test_the_prediction_cache_key_leaves_out_the_model_choice(monkeypatch):
    """A zone's model choice makes no prediction (the calibration names its model): a change to it
    keeps the cached predictions; a change to a module that makes them does not."""
    from importlib.util import find_spec
    from pathlib import Path

    from towerpipe.evaluation import predcache

    key = predcache.inference_code()
    real_read = Path.read_bytes
    choice, sampling = (Path(find_spec(m).origin) for m in ("towerpipe.model.choice", "towerpipe.model.sampling"))

    def edited(target):
        return lambda self: real_read(self) + (b"# edited" if self == target else b"")

    monkeypatch.setattr(Path, "read_bytes", edited(choice))
    assert predcache.inference_code() == key
    monkeypatch.setattr(Path, "read_bytes", edited(sampling))
    assert predcache.inference_code() != key
