"""A tiny end-to-end training run on in-test tiles: losses fall, a bundle loads and runs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_dataset import make_tiles

from towerpipe.model.bundle import load_bundle
from towerpipe.training.ablation import run_ablation
from towerpipe.training.dataset import build_windows
from towerpipe.training.metrics import classification_metrics, segmentation_metrics
from towerpipe.training.train import train_bundle, train_classifier

TINY = {"epochs": 6, "batch_size": 8, "threads": 2, "seed": 0, "progress": False, "arch": "light"}


@pytest.fixture(scope="module")
def windows(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tiles")
    paths = make_tiles(tmp, 5, n_veg=2500, tower_pts=200)
    ws = build_windows(paths, {"n_points": 128, "seed": 0, "random_negatives_per_tile": 4})
    ws.save(tmp / "windows.npz")
    return ws, tmp / "windows.npz"


def test_metrics_by_hand():
    m = classification_metrics(np.array([0.9, 0.8, 0.2, 0.6]), np.array([1, 0, 1, 0]))
    assert (m["precision"], m["recall"]) == (pytest.approx(1 / 3), 0.5) and m["f1"] == pytest.approx(0.4)
    s = segmentation_metrics(np.array([1, 1, 0, 0]), np.array([1, 0, 0, 0]))
    assert s["iou_tower"] == 0.5 and s["iou_background"] == pytest.approx(2 / 3)
    assert s["miou"] == pytest.approx((0.5 + 2 / 3) / 2)


def test_tiny_classifier_learns(windows):
    ws, _ = windows
    model, history, metrics = train_classifier(ws, TINY)
    print("classifier history", [(h["epoch"], round(h["train_loss"], 3), round(h["val_loss"], 3)) for h in history])
    assert history[-1]["train_loss"] < history[0]["train_loss"]
    assert min(h["val_loss"] for h in history) < history[0]["val_loss"] or history[0]["val_loss"] < 0.5
    assert {"f1", "precision", "recall"} <= set(metrics["test"])
    assert metrics["train_time_s"] > 0 and metrics["peak_rss_mb"] > 0


def test_train_bundle_round_trip(windows, tmp_path):
    _, path = windows
    out = train_bundle([path], tmp_path / "towerpipe-full-v2", "full", dict(TINY, epochs=3, segmenter={"epochs": 4}))
    names = {p.name for p in out.iterdir()}
    assert {
        "classifier.pt",
        "segmenter.pt",
        "model_card.json",
        "MODEL_CARD.md",
        "classifier_curves.png",
        "segmenter_curves.png",
    } <= names
    card = json.loads((out / "model_card.json").read_text())
    assert (card["name"], card["version"]) == ("towerpipe-full", "2")  # from the directory's name
    assert card["features"] == ["x", "y", "z", "intensity", "green", "blue", "ndvi"]
    assert card["sampling"]["n_points"] == 128 and len(card["config_hash"]) == 16
    assert card["code"]["towerpipe"]
    seg_hist = json.loads((out / "history.json").read_text())["segmenter"]
    print("segmenter history", [(h["epoch"], round(h["train_loss"], 3)) for h in seg_hist])
    assert seg_hist[-1]["train_loss"] < seg_hist[0]["train_loss"]
    assert {"iou_tower", "iou_background", "miou"} <= set(card["metrics"]["segmenter"]["test"])
    b = load_bundle(out)
    ws, _ = windows
    x, _ = ws.sampled(np.arange(4), "full")
    p = b.classify(x)
    assert p.shape == (4,) and np.all((p >= 0) & (p <= 1))
    f, _ = ws.window_points(int(np.flatnonzero(ws.label == 1)[0]), "full")
    assert b.segment(f).shape == (len(f),)


def test_warm_start_continues_from_a_bundle(windows, tmp_path, random_model_factory):
    import torch

    from towerpipe.errors import ConfigError
    from towerpipe.training.train import _initial, train_config

    _, path = windows
    init = random_model_factory("full")
    cfg = train_config(dict(TINY, init_from=str(init), feature_set="full"))
    start = load_bundle(init)
    for kind in ("classifier", "segmenter"):
        net = _initial(kind, cfg, 7)
        for (k, a), b in zip(net.state_dict().items(), getattr(start, kind).state_dict().values()):
            assert torch.equal(a, b), k
    out = train_bundle(
        [path], tmp_path / "warm", "full", dict(TINY, epochs=1, init_from=str(init), segmenter={"epochs": 1})
    )
    card = json.loads((out / "model_card.json").read_text())
    # a directory without a release names the model itself, release 0: never the shipped model's name
    assert (card["name"], card["version"]) == ("warm", "0")
    assert "warm-started from: `towerpipe-random-full" in (out / "MODEL_CARD.md").read_text()
    rec = card["init_from"]
    assert rec["name"] == "towerpipe-random-full" and set(rec["files_sha256"]) == {
        "classifier.pt",
        "segmenter.pt",
        "classifier.folded.npz",
        "segmenter.folded.npz",
    }
    with pytest.raises(ConfigError, match="geometry"):
        _initial("classifier", train_config(dict(TINY, init_from=str(init), feature_set="geometry")), 3)


def test_ablation_table(windows, tmp_path):
    _, path = windows
    rows = {"reference": {}, "no_rgb_nir": {"feature_set": "geometry"}}
    md = run_ablation([path], tmp_path, dict(TINY, epochs=2), rows=rows, subprocess=False)
    text = md.read_text()
    assert "| reference | PointNet_L | X | X | 0.999 |" in text
    assert "| no_rgb_nir | PointNet_L |  | X | 0.999 |" in text
    assert "IoU tower" in text and "Dropping RGB and NIR" in text
    res = json.loads((tmp_path / "ablation.json").read_text())["results"]
    assert res["no_rgb_nir"]["classifier"]["parameters"] < res["reference"]["classifier"]["parameters"] + 100


def test_a_feature_set_needs_its_attributes_valid_on_every_training_block(tmp_path):
    """A geometry model trained on blocks whose intensity is all 0 (present, not valid) was only
    refused when the night ran it; training refuses it, naming the attribute."""
    from test_dataset import make_tiles

    from towerpipe.errors import ConfigError
    from towerpipe.io.tiles import Tile, load_tile, save_tile

    paths = make_tiles(tmp_path, 3, n_veg=400, tower_pts=60)
    for i, p in enumerate(paths):
        t = load_tile(p)
        valid = ["nir", "rgb"] + ([] if i == 0 else ["intensity"]) + ["returns"]
        save_tile(p, Tile(t.arrays, {**t.meta, "valid_attributes": sorted(valid)}))
    ws = build_windows(
        paths,
        {
            "n_points": 64,
            "seed": 0,
            "random_negatives_per_tile": 2,
            "split": {"val": ["b2"], "test": ["b0"]},
        },
    )
    assert ws.meta["valid_attributes"] == ["nir", "returns", "rgb"]
    ws.save(tmp_path / "w.npz")
    with pytest.raises(ConfigError, match="needs intensity valid on every training block"):
        train_bundle([tmp_path / "w.npz"], tmp_path / "g-v1", "geometry", dict(TINY, epochs=1))
