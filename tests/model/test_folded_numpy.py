"""Folded PointNet in NumPy: the module's probabilities, the bundle's files, no PyTorch at inference."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from conftest import model_card, trained_like
from towerpipe.errors import ModelError
from towerpipe.model.bundle import fold_bundle, load_bundle, save_bundle
from towerpipe.model.cards import default_model_path, read_card
from towerpipe.model.folded import fold_pointnet
from towerpipe.model.folded_numpy import FOLDED_FILES, FoldedPair, has_folded, load_folded, save_folded
from towerpipe.model.lazy import LazyBundle
from towerpipe.model.pointnet import PointNetClassifier, PointNetSegmenter


@pytest.fixture(scope="module")
def pair():
    torch.manual_seed(1)
    return trained_like(PointNetClassifier(7, "compact"), 5), trained_like(PointNetSegmenter(7, "compact"), 6)


def _windows(b: int, n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.5, 0.5, size=(b, n, 7)).astype(np.float32)


@pytest.mark.parametrize("arch", ["compact", "light"])
def test_folded_equals_the_module(arch):
    torch.manual_seed(0)
    clf = trained_like(PointNetClassifier(7, arch), 7)
    seg = trained_like(PointNetSegmenter(7, arch), 8)
    x = _windows(5, 700)
    with torch.no_grad():
        ref_c = clf(torch.from_numpy(x))[0][:, 1].exp().numpy()
        ref_s = seg(torch.from_numpy(x[:1]))[0][0, :, 1].exp().numpy()
    got_c = fold_pointnet(clf).classify(x)
    got_s = fold_pointnet(seg).segment(x[0], chunk=97)  # the max-pools span all chunks
    assert got_c.dtype == np.float32 and got_s.dtype == np.float32
    # float32 sums in another order (NumPy's BLAS against PyTorch's kernels, which differ with
    # the CPU's vector units): probabilities agree to 1e-5, ten times inside the 1e-4
    np.testing.assert_allclose(got_c, ref_c, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(got_s, ref_s, rtol=1e-4, atol=1e-5)
    assert np.unique(got_s).size > 100 and np.ptp(got_c) > 1e-3  # not a constant output


def test_saved_bytes_are_the_same_for_the_same_weights(pair, tmp_path):
    net = fold_pointnet(pair[0])
    a, b = save_folded(net, tmp_path / "a.npz"), save_folded(fold_pointnet(pair[0]), tmp_path / "b.npz")
    assert a.read_bytes() == b.read_bytes()
    x = _windows(3, 300)
    np.testing.assert_array_equal(load_folded(a, "classifier").classify(x), net.classify(x))


def test_load_errors_name_the_file_and_the_fix(pair, tmp_path):
    p = save_folded(fold_pointnet(pair[1]), tmp_path / "seg.npz")
    with pytest.raises(ModelError, match=r"seg.npz: holds a 'segmenter', expected a classifier"):
        load_folded(p, "classifier")
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    with pytest.raises(ModelError, match=r"bad.npz: not a readable folded network.*fold-model"):
        load_folded(tmp_path / "bad.npz", "classifier")
    with pytest.raises(ModelError, match="classify needs a classifier"):
        load_folded(p, "segmenter").classify(_windows(1, 10))


def test_bundle_folded_pair_gives_the_bundles_probabilities(pair, tmp_path):
    out = save_bundle(tmp_path / "m", *pair, model_card())
    card = read_card(out)  # the checksums of the folded files are checked with the others
    assert has_folded(card) and all(card["files"][f] for f in FOLDED_FILES.values())
    b, f = load_bundle(out), FoldedPair(out)
    x = _windows(4, 256, 3)
    np.testing.assert_array_equal(f.classify(x), b.classify(x))
    np.testing.assert_array_equal(f.segment(x[0]), b.segment(x[0]))
    with pytest.raises(ModelError, match=r"classify expects \(B, n, C\)"):
        f.classify(x[0])
    with pytest.raises(ModelError, match=r"segment expects \(N, C\)"):
        f.segment(x)
    (out / FOLDED_FILES["segmenter"]).write_bytes(b"changed")
    with pytest.raises(ModelError, match="segmenter.folded.npz: checksum differs"):
        read_card(out)


def test_fold_bundle_adds_the_copies_to_an_older_bundle(pair, tmp_path):
    out = save_bundle(tmp_path / "m", *pair, model_card())
    card = json.loads((out / "model_card.json").read_text())
    for name in FOLDED_FILES.values():
        (out / name).unlink()
        del card["files"][name]
    (out / "model_card.json").write_text(json.dumps(card))
    md = (out / "MODEL_CARD.md").read_bytes()
    lazy = LazyBundle(out)
    x = _windows(2, 300, 4)
    old = lazy.classify(x)  # no folded files: the checkpoints, through PyTorch
    assert not has_folded(lazy.card) and not isinstance(lazy._bundle, FoldedPair)
    written = fold_bundle(out)
    assert sorted(written) == sorted(FOLDED_FILES.values())
    assert (out / "MODEL_CARD.md").read_bytes() == md
    lazy = LazyBundle(out)
    np.testing.assert_array_equal(lazy.classify(x), old)
    assert isinstance(lazy._bundle, FoldedPair)


@pytest.mark.parametrize("feature_set", ["shape", "geometry"])
def test_shipped_models_run_without_torch(feature_set):
    """An inference job on a shipped model never imports PyTorch, and scores as the checkpoints do: to
    float32 rounding, as NumPy's and PyTorch's kernels sum in their own order (equal to the bit on some
    CPUs, within 4e-7 on an AVX-512 one)."""
    model = default_model_path(feature_set)
    assert has_folded(read_card(model)), f"{model}: run `towerpipe fold-model {model}`"
    n = len(read_card(model)["features"])
    code = (
        "import sys, numpy as np\n"
        "from towerpipe.model.lazy import LazyBundle\n"
        f"b = LazyBundle({str(model)!r})\n"
        f"x = np.random.default_rng(0).uniform(-0.5, 0.5, (3, 2048, {n})).astype(np.float32)\n"
        "p = b.classify(x); s = b.segment(x[0])\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
        "np.save(sys.stdout.buffer, np.r_[p, s])\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, check=True)
    import io

    got = np.load(io.BytesIO(run.stdout))
    b = load_bundle(model)
    x = np.random.default_rng(0).uniform(-0.5, 0.5, (3, 2048, n)).astype(np.float32)
    np.testing.assert_allclose(got, np.r_[b.classify(x), b.segment(x[0])], rtol=0, atol=1e-6)


def test_an_edgeconv_bundle_has_no_folded_copy(tmp_path):
    from towerpipe.model.pointnet import build_model

    clf = build_model({"kind": "classifier", "in_channels": 7, "arch": "edge"})
    seg = build_model({"kind": "segmenter", "in_channels": 7, "arch": "edge"})
    out = save_bundle(tmp_path / "e", clf, seg, model_card())
    assert not has_folded(read_card(out))
    with pytest.raises(ModelError, match="EdgeConv bundle has no folded copy"):
        fold_bundle(out)
