"""The per-point input vector: fixed normalisation, colour bits, NDVI, intensity scale."""

from __future__ import annotations

import math

import numpy as np
import pytest

from towerpipe.errors import ModelError
from towerpipe.model.features import (
    FEATURE_SETS,
    NORM_RADIUS,
    intensity_scale,
    missing_attributes,
    required_attributes,
    tile_feature_meta,
    window_features,
)


def _arrays(n: int = 50, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "x": 400000 + rng.uniform(-20, 20, n),
        "y": 4600000 + rng.uniform(-20, 20, n),
        "hag": rng.uniform(0, 50, n).astype(np.float32),
        "intensity": rng.integers(1, 1000, n).astype(np.uint16),
        "red": rng.integers(0, 256, n).astype(np.uint16),
        "green": rng.integers(0, 256, n).astype(np.uint16),
        "blue": rng.integers(0, 256, n).astype(np.uint16),
        "nir": rng.integers(0, 256, n).astype(np.uint16),
        "return_number": np.ones(n, np.uint8),
        "number_of_returns": rng.integers(1, 4, n).astype(np.uint8),
        "model_input": np.ones(n, bool),
    }


META = {"color_bits": 8, "has_rgb": True, "has_nir": True}


def test_columns_and_values():
    a = _arrays()
    meta = tile_feature_meta(a, META)
    idx = np.arange(50)
    f = window_features(a, idx, (400000.0, 4600000.0), "full", meta)
    assert f.shape == (50, 7) and f.dtype == np.float32
    assert NORM_RADIUS == pytest.approx(math.hypot(20 * math.sqrt(2), 50))
    np.testing.assert_allclose(f[:, 0], (a["x"] - 400000) / NORM_RADIUS, rtol=1e-5)
    np.testing.assert_allclose(f[:, 2], a["hag"] / NORM_RADIUS, rtol=1e-5)
    # every point with HAG <= 50 inside the window lies in the unit sphere
    assert np.all(np.linalg.norm(f[:, :3], axis=1) <= 1 + 1e-6)
    np.testing.assert_allclose(f[:, 4], a["green"] / 255, rtol=1e-5)
    nir, red = a["nir"].astype(float), a["red"].astype(float)
    ndvi = np.where(nir + red > 0, (nir - red) / np.maximum(nir + red, 1), 0)
    np.testing.assert_allclose(f[:, 6], ndvi, rtol=1e-5, atol=1e-7)
    g = window_features(a, idx, (400000.0, 4600000.0), "geometry", meta)
    assert g.shape == (50, len(FEATURE_SETS["geometry"]))


def test_normalisation_does_not_depend_on_the_sample():
    a = _arrays(200)
    meta = tile_feature_meta(a, META)
    full = window_features(a, np.arange(200), (400000.0, 4600000.0), "full", meta)
    part = window_features(a, np.arange(0, 200, 7), (400000.0, 4600000.0), "full", meta)
    np.testing.assert_array_equal(full[::7], part)


def test_colour_bits_and_intensity_scale():
    a = _arrays()
    a16 = dict(a, green=(a["green"].astype(np.uint32) * 257).astype(np.uint16))
    f8 = window_features(a, np.arange(50), (400000.0, 4600000.0), "full", tile_feature_meta(a, META))
    f16 = window_features(
        a16, np.arange(50), (400000.0, 4600000.0), "full", tile_feature_meta(a16, dict(META, color_bits=16))
    )
    np.testing.assert_allclose(f8[:, 4], f16[:, 4], atol=1e-6)
    # doubling every intensity (another sensor) leaves the feature unchanged
    a2 = dict(a, intensity=a["intensity"] * 2)
    fa = window_features(a, np.arange(50), (400000.0, 4600000.0), "geometry", tile_feature_meta(a, META))
    fb = window_features(a2, np.arange(50), (400000.0, 4600000.0), "geometry", tile_feature_meta(a2, META))
    np.testing.assert_allclose(fa[:, 3], fb[:, 3], rtol=1e-6)
    assert intensity_scale(a) == pytest.approx(np.percentile(a["intensity"], 95))
    # without a precomputed scale the same value is used
    fc = window_features(a, np.arange(50), (400000.0, 4600000.0), "geometry", META)
    np.testing.assert_array_equal(fa, fc)


def test_required_attributes_and_missing_colour():
    assert required_attributes("full") == ["intensity", "nir", "rgb"]
    assert required_attributes("rgb") == ["rgb"]
    assert required_attributes("geometry") == ["intensity", "returns"]
    assert required_attributes("shape") == []
    # older tiles: only has_rgb / has_nir flags
    assert missing_attributes("full", {"has_rgb": True, "has_nir": False}) == ["nir"]
    # a tile whose intensity and returns carry nothing (a public re-export)
    meta = {"valid_attributes": ["rgb"]}
    assert missing_attributes("geometry", meta) == ["intensity", "returns"]
    assert missing_attributes("rgb", meta) == [] and missing_attributes("shape", meta) == []
    with pytest.raises(ModelError, match="model: auto"):
        window_features(_arrays(), np.arange(5), (0.0, 0.0), "full", {"has_rgb": False, "has_nir": False})
    with pytest.raises(ModelError, match="unknown feature set"):
        required_attributes("colour")


def test_shape_and_rgb_columns():
    a = _arrays()
    a["red"] = np.full(50, 255, np.uint16)
    meta = tile_feature_meta(a, {**META, "color_bits": 8})
    s = window_features(a, np.arange(50), (400000.0, 4600000.0), "shape", meta)
    assert s.shape == (50, 3)
    r = window_features(a, np.arange(50), (400000.0, 4600000.0), "rgb", meta)
    np.testing.assert_allclose(r[:, 3], 1.0)  # red, 8-bit full scale
    np.testing.assert_array_equal(r[:, :3], s)
