"""The delivery's noise classes and its withheld points: left out of the processing, kept in the output."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from conftest import RGBNIR_SMALL, preprocess_settings
from towerpipe import classes
from towerpipe.io.blockcache import BlockCache
from towerpipe.io.tiles import load_tile
from towerpipe.preprocess.split import split_block
from towerpipe.preprocess.tile import preprocess_tile, summarize_block
from towerpipe.products.merge import merge_block

pytestmark = pytest.mark.shared

#: LiDAR HD (IGN) marks its artefacts 65; RGBNIR_SMALL has 539 of them, some of them tall.
ARTEFACTS = 65


@pytest.fixture
def delivery(tmp_path):
    """RGBNIR_SMALL with every 50th point of classes 1-6 withheld (the flag, its class kept)."""
    las = laspy.read(RGBNIR_SMALL)
    cls = np.asarray(las.classification)
    withheld = np.zeros(len(cls), bool)
    withheld[::50] = True
    withheld &= np.isin(cls, (1, 2, 3, 4, 5, 6))
    las.withheld = withheld
    path = tmp_path / "b.laz"
    las.write(path)
    return path, cls, withheld


def test_noise_classes_and_withheld_points_are_noise_in_the_cache_only(tmp_path, delivery):
    path, cls, withheld = delivery
    settings = preprocess_settings(extra_noise_classes=[ARTEFACTS])
    meta = split_block(path, tmp_path / "cache", block="b", zone="z", settings=settings)
    noise = withheld | np.isin(cls, (7, 18, ARTEFACTS))
    assert meta["noise_points"] == int(noise.sum()) > meta["withheld_points"] == int(withheld.sum()) > 0
    assert meta["noise_classes"] == [7, 18, ARTEFACTS]
    assert meta["class_counts"][str(ARTEFACTS)] == int((cls == ARTEFACTS).sum())  # the input's classes
    cached = BlockCache(tmp_path / "cache").column("classification")
    np.testing.assert_array_equal(cached[noise], classes.LOW_NOISE)
    np.testing.assert_array_equal(cached[~noise], cls[~noise])
    # the default: the ASPRS noise classes and the withheld points only
    meta = split_block(path, tmp_path / "cache_default", block="b", zone="z", settings=preprocess_settings())
    assert meta["noise_classes"] == [7, 18] and meta["noise_points"] == int((withheld | np.isin(cls, (7, 18))).sum())
    np.testing.assert_array_equal(BlockCache(tmp_path / "cache_default").column("classification")[cls == 65], 65)


@pytest.mark.usefixtures("pdal_cli")
def test_they_are_no_ground_and_no_model_input_and_keep_their_class_and_flag_in_the_output(tmp_path, delivery):
    path, cls, withheld = delivery
    settings = preprocess_settings(extra_noise_classes=[ARTEFACTS], tile_size=1000.0)
    meta = split_block(path, tmp_path / "cache", block="b", zone="z", settings=settings)
    (tile,) = meta["tiles"]
    preprocess_tile("z", "b", tile, {"b": tmp_path / "cache"}, tmp_path / "tile.npz", settings=settings)
    t = load_tile(tmp_path / "tile.npz")
    noise = withheld | np.isin(cls, (7, 18, ARTEFACTS))
    order = np.argsort(np.asarray(t.arrays["point_index"]))  # the tile's points in block order
    model_input = np.asarray(t.arrays["model_input"], bool)[order]
    assert not model_input[noise].any() and model_input[~noise].any()
    assert t.meta["counts"]["noise_class_core"] == int(noise.sum())
    summary = summarize_block(tmp_path / "cache", [tmp_path / "tile.npz"])
    assert (summary["noise_points"], summary["withheld_points"]) == (int(noise.sum()), int(withheld.sum()))
    merge_block(path, [], tmp_path / "out.laz", threshold=0.5, records=BlockCache(tmp_path / "cache").records_path)
    out = laspy.read(tmp_path / "out.laz")
    np.testing.assert_array_equal(np.asarray(out.classification), cls)
    np.testing.assert_array_equal(np.asarray(out.withheld, bool), withheld)
