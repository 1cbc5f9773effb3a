"""The jobs' steps (towerpipe.jobs.steps): a tile's preprocessing and inference in one job."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import RGBNIR_SMALL, grid_inference, preprocess_settings
from towerpipe.io.columns import load_columns
from towerpipe.io.conductors import CONDUCTOR_ARRAYS
from towerpipe.io.predictions import PRED_ARRAYS
from towerpipe.io.tiles import TILE_ARRAYS
from towerpipe.jobs.steps import infer_step, tile_step
from towerpipe.preprocess.split import split_block
from towerpipe.preprocess.tile import preprocess_tile

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.shared]


def _same(a, b, names):
    (xa, ma), (xb, mb) = load_columns(a, list(names), "test", ""), load_columns(b, list(names), "test", "")
    for k in names:
        assert xa[k].dtype == xb[k].dtype and np.array_equal(xa[k], xb[k], equal_nan=True), k
    drop = {"timings", "peak_rss_mb", "windows_per_s_classify"}
    assert {k: v for k, v in ma.items() if k not in drop} == {k: v for k, v in mb.items() if k not in drop}


def test_tile_step_equals_a_preprocessing_job_then_an_inference_job(tmp_path, random_model_factory):
    """The tile job of a zone with products writes the tile, predictions and conductor points
    that a preprocessing job and an inference job reading its file write."""
    prep, inference = preprocess_settings(tile_size=100.0), grid_inference(gate=0.0)  # every window segmented
    cache = tmp_path / "cache" / "b"
    meta = split_block(RGBNIR_SMALL, cache, block="b", zone="z", settings=prep)
    t = meta["tiles"][0]  # a tile with points (the split's occupied tiles)
    model = random_model_factory("shape")
    a, b = tmp_path / "two_jobs", tmp_path / "one_job"
    preprocess_tile("z", "b", t, {"b": cache}, a / "tile.npz", dtm_path=a / "dtm.tif", settings=prep)
    infer_step(a / "tile.npz", model, a / "pred.npz", inference, out_wires=a / "wires.npz")
    tile_step(
        "z",
        "b",
        t,
        {"b": cache},
        b / "tile.npz",
        b / "pred.npz",
        dtm_path=b / "dtm.tif",
        preprocess=prep,
        inference=inference,
        out_wires=b / "wires.npz",
        model=model,
    )
    _same(a / "tile.npz", b / "tile.npz", TILE_ARRAYS)
    _same(a / "pred.npz", b / "pred.npz", PRED_ARRAYS)
    _same(a / "wires.npz", b / "wires.npz", CONDUCTOR_ARRAYS)
    assert load_columns(b / "pred.npz", ["prob"], "test", "")[0]["prob"].size > 0  # windows were segmented
