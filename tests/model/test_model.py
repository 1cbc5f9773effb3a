"""PointNet_L / PointNet: parameter counts, permutation invariance, chunked segmentation, checkpoints."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from conftest import REPO, model_card, trained_like
from towerpipe.errors import ModelError
from towerpipe.model.bundle import load_bundle, save_bundle
from towerpipe.model.cards import MODEL_RELEASES, default_model_path, validate_card
from towerpipe.model.folded import segment_points
from towerpipe.model.pointnet import PointNetClassifier, PointNetSegmenter, count_parameters, max_pool

torch.set_num_threads(2)


def test_parameter_counts_match_paper():
    counts = {
        (arch, kind): count_parameters(cls(7, arch))
        for arch in ("light", "full")
        for kind, cls in (("classifier", PointNetClassifier), ("segmenter", PointNetSegmenter))
    }
    for key, n in counts.items():
        print(f"{key[0]:>5} {key[1]:<10} {n:>9,d} parameters")
    # paper: PointNet_L ~0.9 M, PointNet ~3.5 M
    assert counts[("light", "classifier")] == pytest.approx(0.9e6, rel=0.05)
    assert counts[("light", "segmenter")] == pytest.approx(0.9e6, rel=0.05)
    assert counts[("full", "classifier")] == pytest.approx(3.5e6, rel=0.05)
    assert counts[("full", "segmenter")] == pytest.approx(3.5e6, rel=0.05)


@pytest.mark.parametrize("arch", ["light", "full"])
def test_permutation_invariance(arch):
    torch.manual_seed(0)
    x = torch.randn(3, 300, 7)
    perm = torch.randperm(300)
    clf = trained_like(PointNetClassifier(7, arch))
    seg = trained_like(PointNetSegmenter(7, arch), 1)
    with torch.no_grad():
        a, _ = clf(x)
        b, _ = clf(x[:, perm])
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
        s1, _ = seg(x)
        s2, _ = seg(x[:, perm])
        torch.testing.assert_close(s1[:, perm], s2, rtol=1e-4, atol=1e-5)
        assert torch.allclose(a.exp().sum(-1), torch.ones(3))


def test_max_pool_has_amax_values_and_gradient_sums():
    """The pooling the networks train with: amax's values; the same gradient without ties, the same
    sum over the tied points (duplicated sample points) with them."""
    torch.manual_seed(0)
    h = torch.relu(torch.randn(4, 64, 32))
    h[:, 10] = h[:, 3]  # a duplicated point: ties for every channel where it holds the maximum
    w = torch.randn(4, 32)
    grads = []
    for pool in (max_pool, lambda t: t.amax(dim=1)):
        x = h.clone().requires_grad_(True)
        (pool(x) * w).sum().backward()
        grads.append(x.grad)
    torch.testing.assert_close(max_pool(h), h.amax(dim=1), rtol=0, atol=0)
    untied = torch.ones(4, 64, dtype=torch.bool)
    untied[:, [3, 10]] = False
    torch.testing.assert_close(grads[0][untied], grads[1][untied], rtol=0, atol=0)
    torch.testing.assert_close(grads[0][:, [3, 10]].sum(1), grads[1][:, [3, 10]].sum(1))
    assert grads[0].abs().sum() > 0


def test_segment_chunked_equals_unchunked():
    torch.manual_seed(0)
    seg = trained_like(PointNetSegmenter(6, "light"), 2)
    x = np.random.default_rng(0).uniform(-0.5, 0.5, size=(5000, 6)).astype(np.float32)
    whole = segment_points(seg, x, chunk=10**6)
    chunked = segment_points(seg, x, chunk=777)
    with torch.no_grad():
        ref = seg(torch.from_numpy(x)[None])[0][0, :, 1].exp().numpy()
    np.testing.assert_allclose(whole, ref, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(chunked, ref, rtol=1e-4, atol=1e-6)
    assert np.unique(chunked).size > 100  # point-dependent output, not a constant


def test_bundle_round_trip(tmp_path):
    clf = trained_like(PointNetClassifier(7, "light"), 3)
    seg = trained_like(PointNetSegmenter(7, "light"), 4)
    out = save_bundle(tmp_path / "m", clf, seg, model_card())
    assert sorted(p.name for p in out.iterdir()) == [
        "MODEL_CARD.md",
        "classifier.folded.npz",
        "classifier.pt",
        "model_card.json",
        "segmenter.folded.npz",
        "segmenter.pt",
    ]
    b = load_bundle(out)
    assert (b.name, b.version, b.feature_set, b.n_points) == ("towerpipe-full", "1", "full", 2048)
    x = np.random.default_rng(1).normal(size=(4, 256, 7)).astype(np.float32)
    with torch.no_grad():
        ref = clf(torch.from_numpy(x))[0][:, 1].exp().numpy()
    np.testing.assert_allclose(b.classify(x), ref, rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(b.segment(x[0]), segment_points(seg, x[0]))
    assert b.classify(x).shape == (4,) and b.segment(x[0]).shape == (256,)


def test_load_errors_name_file_and_fix(tmp_path):
    with pytest.raises(ModelError, match="not found"):
        load_bundle(tmp_path / "nope")
    out = save_bundle(tmp_path / "m", PointNetClassifier(7), PointNetSegmenter(7), model_card())
    card = json.loads((out / "model_card.json").read_text())
    del card["features"]
    (out / "model_card.json").write_text(json.dumps(card))
    with pytest.raises(ModelError, match=r"model_card.json.*retrain"):
        load_bundle(out)
    out2 = save_bundle(tmp_path / "m2", PointNetClassifier(7), PointNetSegmenter(7), model_card())
    (out2 / "segmenter.pt").write_bytes(b"garbage")
    with pytest.raises(ModelError, match="segmenter.pt"):
        load_bundle(out2)
    with pytest.raises(ModelError, match="features"):
        validate_card(dict(model_card(), features=["x", "y"]))


def test_default_model_path(monkeypatch, tmp_path):
    monkeypatch.delenv("TOWERPIPE_MODELS", raising=False)
    p = default_model_path("geometry")
    assert p.name == f"towerpipe-geometry-v{MODEL_RELEASES['geometry']}" and p.parent.name == "models"
    assert (p.parent.parent / "pyproject.toml").is_file()
    monkeypatch.setenv("TOWERPIPE_MODELS", str(tmp_path))
    assert default_model_path() == tmp_path / f"towerpipe-shape-v{MODEL_RELEASES['shape']}"


def test_a_card_names_its_architecture_and_its_warm_start():
    """The card's text said PointNet_L whatever the widths; a warm start showed only in the config."""
    import json

    from towerpipe.model.cards import card_markdown

    shipped = json.loads((REPO / "models" / "towerpipe-shape-v3" / "model_card.json").read_text())
    md = card_markdown(shipped)
    assert "a compact PointNet: PointNet_L with half its global width" in md and "warm-started" not in md
    assert (REPO / "models" / "towerpipe-shape-v3" / "MODEL_CARD.md").read_text().splitlines()[2] == md.splitlines()[2]
    init = {"name": "towerpipe-shape", "version": "3", "path": "models/towerpipe-shape-v3"}
    tuned = card_markdown({**shipped, "architecture": {"arch": "light"}, "init_from": init})
    assert "PointNet_L, the light PointNet" in tuned
    assert "- warm-started from: `towerpipe-shape v3 (models/towerpipe-shape-v3)`" in tuned
