"""The per-point input vector: fixed normalisation, colour bits, NDVI, intensity scale."""

from __future__ import annotations

import math

import numpy as np
import pytest

from towerpipe.errors import ModelError
from towerpipe.model.features import (
    FEATURE_SETS,
    LOCAL_STRUCTURE,
    NORM_RADIUS,
    intensity_scale,
    local_structure,
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


def _lattice_and_crown(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A vertical member (a leg), a horizontal one (a crossarm) and a crown-like ball of points."""
    rng = np.random.default_rng(seed)
    leg = np.c_[rng.normal(0, 0.03, 40), rng.normal(0, 0.03, 40), np.linspace(2, 20, 40)]
    arm = np.c_[np.linspace(8, 16, 30), rng.normal(0, 0.03, 30), 18 + rng.normal(0, 0.03, 30)]
    crown = np.c_[-10 + rng.normal(0, 1.5, 80), rng.normal(0, 1.5, 80), 12 + rng.normal(0, 1.5, 80)]
    pts = np.r_[leg, arm, crown]
    kind = np.r_[np.zeros(40), np.ones(30), np.full(80, 2)].astype(int)
    return pts[:, 0], pts[:, 1], pts[:, 2], kind


def test_local_structure_tells_members_from_crowns():
    x, y, h, kind = _lattice_and_crown()
    f = local_structure(x, y, h)
    assert f.shape == (len(x), len(LOCAL_STRUCTURE)) and f.dtype == np.float32
    assert ((f >= 0) & (f <= 1)).all()
    lin, _, scat, vert = f.T
    leg, arm, crown = (kind == 0), (kind == 1), (kind == 2)
    assert np.median(lin[leg]) > 0.9 and np.median(vert[leg]) > 0.9  # a vertical line
    assert np.median(lin[arm]) > 0.9 and np.median(vert[arm]) < 0.1  # a horizontal line
    assert np.median(scat[crown]) > 5 * np.median(scat[leg | arm])  # a volume
    assert np.median(lin[crown]) < 0.6


def test_local_structure_ignores_offset_rotation_and_order():
    x, y, h, _ = _lattice_and_crown(1)
    f = local_structure(x, y, h)
    a = 0.7
    xr, yr = x * np.cos(a) - y * np.sin(a), x * np.sin(a) + y * np.cos(a)
    np.testing.assert_allclose(local_structure(xr + 400000.0, yr + 4600000.0, h), f, atol=1e-4)
    perm = np.random.default_rng(2).permutation(len(x))
    np.testing.assert_allclose(local_structure(x[perm], y[perm], h[perm]), f[perm], atol=1e-5)
    assert local_structure(x[:2], y[:2], h[:2]).tolist() == [[0.0] * 4] * 2


def test_structure_columns_of_a_sample_are_those_of_the_whole_window():
    """A sampled point keeps the structure it has among all the window's points, in training as
    at inference: the classifier's sample and the segmenter's whole window agree."""
    x, y, h, _ = _lattice_and_crown(3)
    a = {"x": 400000.0 + x, "y": 4600000.0 + y, "hag": h.astype(np.float32)}
    idx = np.arange(len(x))
    meta = {"valid_attributes": []}
    full = window_features(a, idx, (400000.0, 4600000.0), "structure", meta)
    assert full.shape == (len(x), 7) and FEATURE_SETS["structure"][:3] == ["x", "y", "z"]
    sample = np.array([5, 5, 60, 149, 0])
    part = window_features(a, idx, (400000.0, 4600000.0), "structure", meta, sample)
    np.testing.assert_array_equal(part, full[sample])
    alone = window_features(a, idx[sample], (400000.0, 4600000.0), "structure", meta)
    assert not np.allclose(alone[:, 3:], part[:, 3:])  # among the sample alone they would differ
    np.testing.assert_array_equal(part[:, :3], window_features(a, idx, (400000.0, 4600000.0), "shape", meta, sample))
