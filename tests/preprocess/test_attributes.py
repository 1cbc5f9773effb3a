"""Sensor attribute validity: decided from the points, recorded by the split, shown to QA."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from conftest import RGB_SUBSET, RGBNIR_SMALL, preprocess_settings
from towerpipe.preprocess.attributes import ATTRIBUTES, MIN_DISTINCT, AttributeStats, degenerate, describe, valid_set

DIMS = ["x", "y", "z", "intensity", "return_number", "number_of_returns", "red", "green", "blue", "nir"]


def _chunk(n=1000, seed=0, **over):
    rng = np.random.default_rng(seed)
    c = {
        "intensity": rng.integers(0, 4000, n).astype(np.uint16),
        "return_number": rng.integers(1, 3, n).astype(np.uint8),
        "number_of_returns": rng.integers(2, 4, n).astype(np.uint8),
        "red": rng.integers(0, 65535, n).astype(np.uint16),
        "green": rng.integers(0, 65535, n).astype(np.uint16),
        "blue": rng.integers(0, 65535, n).astype(np.uint16),
        "nir": rng.integers(0, 65535, n).astype(np.uint16),
    }
    for k, v in over.items():
        c[k] = np.full(n, v, c[k].dtype)
    return c


def test_informative_attributes_are_valid():
    s = AttributeStats(DIMS)
    s.update(_chunk())
    r = s.result()
    assert all(r[a]["valid"] for a in ATTRIBUTES)
    assert degenerate(r) == [] and valid_set(r) == set(ATTRIBUTES)


def test_a_public_reexport_with_zeroed_attributes():
    """Intensity, returns all 0 and a NIR of zeros: degenerate, not absent."""
    s = AttributeStats(DIMS)
    for k in range(3):  # every chunk of the file is the same
        s.update(_chunk(seed=k, intensity=0, return_number=0, number_of_returns=0, nir=0))
    r = s.result()
    assert not r["intensity"]["valid"] and r["intensity"]["reason"] == "all 0"
    assert not r["returns"]["valid"] and "all 0" in r["returns"]["reason"]
    assert not r["nir"]["valid"] and r["rgb"]["valid"]
    assert degenerate(r) == ["intensity", "returns", "nir"]
    assert "returns: return numbers all 0" in describe(r)


def test_constant_and_few_values_carry_nothing():
    s = AttributeStats(DIMS)
    s.update(_chunk(red=1000, green=1000, blue=1000, return_number=1, number_of_returns=1))
    r = s.result()
    assert not r["rgb"]["valid"] and "1 distinct value" in r["rgb"]["reason"]
    assert not r["returns"]["valid"] and "return 1 of 1" in r["returns"]["reason"]
    few = AttributeStats(DIMS)
    c = _chunk()
    c["intensity"] = (np.arange(1000) % MIN_DISTINCT).astype(np.uint16) + 1
    few.update(c)
    assert not few.result()["intensity"]["valid"]
    c["intensity"] = (np.arange(1000) % (MIN_DISTINCT + 1)).astype(np.uint16)
    more = AttributeStats(DIMS)
    more.update(c)
    assert more.result()["intensity"]["valid"]


def test_values_spread_over_chunks_count_together():
    s = AttributeStats(DIMS)
    for v in range(MIN_DISTINCT + 1):  # one value per chunk
        s.update(_chunk(n=10, intensity=v))
    assert s.result()["intensity"]["valid"]


def test_missing_dimensions_are_absent_not_degenerate():
    s = AttributeStats(["x", "y", "z", "intensity", "return_number", "number_of_returns"])
    s.update({k: v for k, v in _chunk().items() if k in ("intensity", "return_number", "number_of_returns")})
    r = s.result()
    assert not r["rgb"]["present"] and not r["rgb"]["valid"] and r["nir"]["reason"] == "not in the point format"
    assert degenerate(r) == []
    assert valid_set(None) == set()


@pytest.mark.usefixtures("pdal_cli")
@pytest.mark.shared
def test_split_records_validity_of_a_real_tile(tmp_path):
    """ign_rgb_subset.laz has a NIR channel of zeros: recorded, flagged, the block keeps its RGB."""
    from towerpipe.preprocess.split import split_block
    from towerpipe.preprocess.tile import summarize_block

    meta = split_block(RGB_SUBSET, tmp_path / "cache", block="b", zone="z", settings=preprocess_settings())
    assert meta["attributes"]["nir"] == {"present": True, "valid": False, "reason": "all 0"}
    assert meta["attributes"]["rgb"]["valid"] and meta["attributes"]["intensity"]["valid"]
    assert meta["degenerate_attributes"] == ["nir"]
    assert meta["has_rgb"] and not meta["has_nir"]
    summary = summarize_block(tmp_path / "cache", [])
    assert summary["degenerate_attributes"] == ["nir"]
    assert any("nir (all 0)" in w for w in summary["warnings"])


@pytest.mark.usefixtures("pdal_cli")
@pytest.mark.shared
def test_split_of_a_zeroed_reexport(tmp_path):
    """A real tile re-exported with intensity and returns zeroed (as public derivatives are)."""
    from towerpipe.preprocess.split import split_block

    las = laspy.read(RGBNIR_SMALL)
    las.intensity[:] = 0
    las.return_number[:] = 0
    las.number_of_returns[:] = 0
    path = tmp_path / "zeroed.laz"
    las.write(path)
    meta = split_block(path, tmp_path / "cache", block="b", zone="z", settings=preprocess_settings())
    assert meta["degenerate_attributes"] == ["intensity", "returns"]
    assert valid_set(meta["attributes"]) == {"rgb", "nir"}


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32, np.int16, np.float32])
def test_distinct_values_are_numpys_whatever_the_dimension_type(dtype):
    """The LAS dimensions' distinct values (counted for 8- and 16-bit ones) are ``np.unique``'s."""
    from towerpipe.preprocess.attributes import _distinct

    for n in (0, 1, 5_000):
        v = np.random.default_rng(n).integers(0, 250, n).astype(dtype)
        assert _distinct(v).tolist() == np.unique(v).tolist()
