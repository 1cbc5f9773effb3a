"""Tests of the prediction-file contract (towerpipe.io.predictions)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from towerpipe.errors import InputError
from towerpipe.io.predictions import PRED_ARRAYS, PRED_META_KEYS, PredFile, empty_pred_arrays, load_pred, save_pred


def _meta(**kw):
    meta = {k: None for k in PRED_META_KEYS}
    meta.update(zone="z", block="b1", tile="t3", blocks=["b0", "b1"], windows_total=7, timings={"total": 1.5})
    meta.update(kw)
    return meta


def _arrays(n=5, seed=0):
    rng = np.random.default_rng(seed)
    return {
        "block_id": np.array([1, 1, 0, 1, 0][:n]),  # int64 on purpose: cast to int32
        "point_index": rng.integers(0, 10**9, n),
        "x": rng.uniform(4e5, 4.1e5, n),
        "y": rng.uniform(4.6e6, 4.7e6, n),
        "z": rng.uniform(0, 300, n),
        "hag": rng.uniform(0, 50, n).astype(np.float32),
        "prob": rng.random(n),  # float64: cast to float32
        "prob_single": rng.random(n),
    }


def test_roundtrip_dtypes_and_meta(tmp_path):
    arrays = _arrays()
    path = tmp_path / "pred" / "b1" / "t3.npz"
    save_pred(path, arrays, _meta())
    pred = load_pred(path)
    assert isinstance(pred, PredFile) and len(pred) == 5
    for name, dtype in PRED_ARRAYS.items():
        assert pred[name].dtype == dtype
        np.testing.assert_array_equal(pred[name], arrays[name].astype(dtype))
    assert pred.meta["windows_total"] == 7 and pred.meta["timings"] == {"total": 1.5}
    assert pred.meta["format_version"] == 2
    assert not list(path.parent.glob("*.part"))
    # uncompressed npz: arrays stored (zip "stored" method)
    import zipfile

    with zipfile.ZipFile(path) as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_STORED}


def test_for_block_selects_rows(tmp_path):
    save_pred(tmp_path / "p.npz", _arrays(), _meta())
    pred = load_pred(tmp_path / "p.npz")
    rows = pred.for_block("b1")
    np.testing.assert_array_equal(rows["point_index"], pred["point_index"][[0, 1, 3]])
    assert len(pred.for_block("nope")["prob"]) == 0


def test_one_view_prediction_gets_prob_single(tmp_path):
    """A prediction without ``prob_single`` is one view: its ``prob`` is the single view."""
    arrays = _arrays()
    del arrays["prob_single"]
    save_pred(tmp_path / "p.npz", arrays, _meta())
    pred = load_pred(tmp_path / "p.npz")
    np.testing.assert_array_equal(pred["prob_single"], pred["prob"])


def test_stale_prediction_without_prob_single_names_the_fix(tmp_path):
    from towerpipe.io.columns import save_columns

    arrays = {k: np.asarray(v).astype(PRED_ARRAYS[k]) for k, v in _arrays().items() if k != "prob_single"}
    save_columns(tmp_path / "old.npz", arrays, dict(_meta(), format_version=1))
    with pytest.raises(InputError, match="prob_single.*rerun the inference|rerun the inference.*prob_single"):
        load_pred(tmp_path / "old.npz")


def test_empty_prediction_file(tmp_path):
    save_pred(tmp_path / "e.npz", empty_pred_arrays(0), _meta())
    assert len(load_pred(tmp_path / "e.npz")) == 0


def test_invalid_inputs_raise(tmp_path):
    arrays = _arrays()
    del arrays["prob"]
    with pytest.raises(InputError, match="prob"):
        save_pred(tmp_path / "a.npz", arrays, _meta())
    bad = _arrays()
    bad["hag"] = bad["hag"][:3]
    with pytest.raises(InputError, match="hag"):
        save_pred(tmp_path / "b.npz", bad, _meta())
    meta = _meta()
    del meta["combine"]
    with pytest.raises(InputError, match="combine"):
        save_pred(tmp_path / "c.npz", _arrays(), meta)
    assert not list(tmp_path.glob("*"))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="rerun the inference"):
        load_pred(tmp_path / "junk.npz")
    # a file missing an array (written by something else) is rejected on load
    np.savez(
        tmp_path / "partial.npz",
        meta=np.frombuffer(json.dumps(_meta()).encode(), np.uint8),
        **{k: v for k, v in _arrays().items() if k != "x"},
    )
    with pytest.raises(InputError):
        load_pred(tmp_path / "partial.npz")
