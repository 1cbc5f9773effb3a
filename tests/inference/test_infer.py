"""Tests of gated window inference (towerpipe.inference.infer): plumbing, not model quality.

A test double implements the ModelBundle interface: its classifier says "tower" when a
window's sampled points hold a tall narrow column, its segmenter thresholds normalised
height (with a window-position term so that overlapping windows disagree and the
combine rule is observable).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import grid_inference, inference_settings, tower_among_crowns, towers_side_by_side
from towerpipe.errors import ConfigError, ModelError
from towerpipe.inference.compat import check_model_compatibility
from towerpipe.inference.infer import infer_tile, predict_tile
from towerpipe.inference.views import TTA_CHOICES, segment_views
from towerpipe.inference.wire_mask import overhead_wires
from towerpipe.io.predictions import PRED_META_KEYS, load_pred
from towerpipe.io.tiles import Tile, empty_arrays, save_tile
from towerpipe.model import features
from towerpipe.towers.wires import WIRE_MIN_HAG_M

R = features.NORM_RADIUS
CORE = (400000.0, 4600000.0, 400160.0, 4600160.0)
TOWER = (400090.0, 4600110.0)  # lies in windows kx in {20003, 20004}, ky in {230004, 230005}


class FakeBundle:
    """ModelBundle double on the ``geometry`` features (x, y, z are columns 0, 1, 2)."""

    name = "fake"
    version = "0"
    feature_set = "geometry"
    card: dict = {}

    def __init__(self, n_points: int = 256):
        self.n_points = n_points
        self.batch_sizes: list[int] = []
        self.segment_sizes: list[int] = []

    def classify(self, feats: np.ndarray) -> np.ndarray:
        assert feats.dtype == np.float32 and feats.ndim == 3 and feats.shape[1] == self.n_points
        self.batch_sizes.append(feats.shape[0])
        out = np.zeros(feats.shape[0], dtype=np.float32)
        for b, f in enumerate(feats):
            tall = f[:, 2] * R > 12.0
            if tall.sum() >= 5:
                spread = (f[tall, :2] * R).std(axis=0).max()
                # depends on which points were sampled: exposes sampling non-determinism
                out[b] = 0.5 + 0.5 * min(1.0, tall.mean()) if spread < 3.0 else 0.1
        return out

    def segment(self, feats: np.ndarray) -> np.ndarray:
        assert feats.dtype == np.float32 and feats.ndim == 2
        self.segment_sizes.append(len(feats))
        return fake_segment(feats[:, 0], feats[:, 2])


def fake_segment(xn: np.ndarray, zn: np.ndarray) -> np.ndarray:
    """Tall points are tower; the x position in the window modulates the probability."""
    return np.where(zn * R > 5.0, np.clip(0.6 + xn, 0.0, 1.0), 0.0).astype(np.float32)


def make_tile(seed: int = 0, tower: tuple[float, float] | None = TOWER, density: float = 0.6) -> Tile:
    """Vegetation (HAG 0.5-6 m), ground, noise and an optional 4x4 m lattice column to 35 m."""
    rng = np.random.default_rng(seed)
    xmin, ymin, xmax, ymax = CORE
    area = (xmax - xmin + 80) * (ymax - ymin + 80)
    n_veg, n_ground = int(area * density), int(area * density / 2)
    n_tower = 400 if tower else 0
    n = n_veg + n_ground + n_tower + 5
    a = empty_arrays(n)
    x = rng.uniform(xmin - 40, xmax + 40, n)
    y = rng.uniform(ymin - 40, ymax + 40, n)
    hag = np.zeros(n, np.float32)
    hag[:n_veg] = rng.uniform(0.5, 6.0, n_veg)
    if tower:
        s = slice(n_veg + n_ground, n_veg + n_ground + n_tower)
        x[s] = tower[0] + rng.uniform(-2, 2, n_tower)
        y[s] = tower[1] + rng.uniform(-2, 2, n_tower)
        hag[s] = rng.uniform(0.5, 35.0, n_tower)
    hag[-5:] = 300.0  # noise, not model input
    a["x"], a["y"] = x, y
    a["hag"] = hag
    a["z"] = 200.0 + hag.astype(np.float64) + 0.01 * (x - xmin)
    a["intensity"] = rng.integers(0, 4000, n).astype(np.uint16)
    a["return_number"] = np.ones(n, np.uint8)
    a["number_of_returns"] = rng.integers(1, 4, n).astype(np.uint8)
    a["classification"] = np.where(hag == 0, 2, 1).astype(np.uint8)
    a["classification"][-5:] = 7
    # east buffer comes from the neighbouring block
    a["block_id"] = np.where(x >= xmax, 1, 0).astype(np.int32)
    a["point_index"] = rng.permutation(n).astype(np.int64)
    a["core"] = (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)
    a["model_input"] = (hag > 0.3) & (hag < 100)
    meta = {
        "zone": "z",
        "block": "b0",
        "tile": "t0",
        "crs_wkt": "",
        "core_bounds": list(CORE),
        "buffer": 40.0,
        "blocks": ["b0", "b1"],
        "has_rgb": False,
        "has_nir": False,
        "color_bits": 16,
        "ground_source": "class2",
        "counts": {},
        "timings": {},
    }
    return Tile(a, meta)


def expected_probs(tile: Tile, passed_keys: list[tuple[int, int]], combine: str, window=40.0):
    """Independent reference: combine fake_segment over the passed windows containing each point."""
    a = tile.arrays
    sel = np.flatnonzero(a["core"] & a["model_input"])
    vals = [[] for _ in sel]
    for kx, ky in passed_keys:
        ox, oy = kx * 20.0, ky * 20.0
        inside = (a["x"][sel] >= ox) & (a["x"][sel] < ox + window) & (a["y"][sel] >= oy) & (a["y"][sel] < oy + window)
        cx = ox + window / 2
        p = fake_segment(((a["x"][sel] - cx) / R).astype(np.float32), (a["hag"][sel] / R).astype(np.float32))
        for j in np.flatnonzero(inside):
            vals[j].append(p[j])
    keep = np.array([len(v) > 0 for v in vals], bool)
    comb = np.array([(max(v) if combine == "max" else np.mean(v)) if v else 0.0 for v in vals], np.float32)
    # the tile classifies no wire: what the wire detector finds is never tower (test_wires_are_never_tower...)
    mi = np.flatnonzero(a["model_input"])
    wire = np.zeros(len(a["x"]), bool)
    wire[mi] = overhead_wires(a, mi, WIRE_MIN_HAG_M)
    comb[wire[sel]] = 0.0
    return sel[keep], comb[keep]


def by_id(arrays):
    order = np.lexsort((arrays["point_index"], arrays["block_id"]))
    return {k: v[order] for k, v in arrays.items()}


def assert_same(a, b):
    """Two predictions hold the same points with the same values."""
    a, b = by_id(a), by_id(b)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


# ----------------------------------------------------------------------------- gating


def test_gate_counts_and_tower_windows():
    tile = make_tile()
    bundle = FakeBundle()
    out, st = predict_tile(tile, bundle, grid_inference(batch_size=8))
    # 160 m core + windows reaching into the buffer: (160/20 + 1)^2 windows with core points
    assert st["windows_total"] + st["windows_empty"] == 81
    passed = sorted((k[0], k[1]) for k in st["window_probs"])
    assert passed == [(20003, 230004), (20003, 230005), (20004, 230004), (20004, 230005)]
    assert st["windows_passed_gate"] == st["windows_segmented"] == 4 == len(bundle.segment_sizes)
    assert sum(bundle.batch_sizes) == st["windows_total"] and max(bundle.batch_sizes) == 8
    assert st["windows_passed_gate"] / st["windows_total"] <= 0.1
    # points of segmented windows: all of their points went to the segmenter
    assert all(s > bundle.n_points for s in bundle.segment_sizes)
    assert len(out["prob"]) == st["points_predicted"] > 0


def test_no_tower_no_segmentation(tmp_path):
    tile = make_tile(tower=None)
    save_tile(tmp_path / "t.npz", tile)
    bundle = FakeBundle()
    meta = infer_tile(tmp_path / "t.npz", bundle, tmp_path / "p.npz", grid_inference())
    pred = load_pred(tmp_path / "p.npz")
    assert len(pred) == 0 and meta["windows_passed_gate"] == 0 and bundle.segment_sizes == []
    assert meta["windows_total"] > 0


def test_height_prefilter_skips_low_windows_without_changing_results():
    tile = make_tile(density=0.3)
    b_all, b_pre = FakeBundle(), FakeBundle()
    ref, st_ref = predict_tile(tile, b_all, grid_inference())
    out, st = predict_tile(tile, b_pre, grid_inference(min_height=10.0))
    assert st["windows_classified"] == 4 and st["windows_prefiltered"] == st["windows_total"] - 4
    assert sum(b_pre.batch_sizes) == 4
    assert st["window_probs"] == st_ref["window_probs"]
    for k in ref:
        np.testing.assert_array_equal(ref[k], out[k])


def test_gate_threshold_zero_segments_every_window():
    tile = make_tile(density=0.2)
    _, st = predict_tile(tile, FakeBundle(), grid_inference(gate=0.0))
    assert st["windows_segmented"] == st["windows_total"]


# ----------------------------------------------------------------------------- combine, ownership


def test_segment_views_are_exact_turns_and_mirrors():
    """Each view is the window turned (and mirrored) about its centre: a segmenter that only
    looks at the distance from the centre scores every view the same; one that looks at the
    x position averages over x -> -x, y, -y, (and x again) for 2, 4, 8 views."""

    class Radial(FakeBundle):
        def segment(self, feats):
            return np.hypot(feats[:, 0], feats[:, 1]).astype(np.float32)

    class East(FakeBundle):
        def segment(self, feats):
            return feats[:, 0].copy()

    rng = np.random.default_rng(0)
    f = rng.uniform(-1, 1, (50, 6)).astype(np.float32)
    x, y = f[:, 0], f[:, 1]
    for views in TTA_CHOICES:
        single, mean = segment_views(Radial(), f, views)
        np.testing.assert_allclose(mean, np.hypot(x, y), rtol=1e-6)
        np.testing.assert_array_equal(single, np.hypot(x, y).astype(np.float32))
    single, mean = segment_views(East(), f, 1)
    assert mean is single
    np.testing.assert_allclose(segment_views(East(), f, 2)[1], 0.0, atol=1e-7)  # x and -x
    np.testing.assert_allclose(segment_views(East(), f, 4)[1], 0.0, atol=1e-7)  # x, -x, -y, y
    np.testing.assert_array_equal(segment_views(East(), f, 8)[0], x)
    np.testing.assert_allclose(f[:, :2], np.stack([x, y], 1))  # the input is not modified
    with pytest.raises(ConfigError, match="tta"):
        segment_views(East(), f, 3)


def test_views_keep_the_single_view_and_average_the_others():
    tile = make_tile()
    one, _ = predict_tile(tile, FakeBundle(), grid_inference())
    two, st = predict_tile(tile, FakeBundle(), grid_inference(tta=2))
    assert st["tta"] == 2
    np.testing.assert_array_equal(one["point_index"], two["point_index"])
    np.testing.assert_array_equal(one["prob_single"], two["prob_single"])
    np.testing.assert_array_equal(one["prob"], one["prob_single"])
    # fake_segment is 0.6 + x on tall points: x and -x average to at most 0.6
    assert (two["prob_single"] > 0.7).any()
    assert (two["prob"] <= 0.6 + 1e-6).all()


@pytest.mark.parametrize("combine", ["max", "mean"])
def test_combine_rule_matches_reference(combine):
    tile = make_tile(density=0.3)
    out, st = predict_tile(tile, FakeBundle(), grid_inference(combine=combine))
    keys = [(k[0], k[1]) for k in st["window_probs"]]
    sel, want = expected_probs(tile, keys, combine)
    a = tile.arrays
    np.testing.assert_array_equal(out["point_index"], a["point_index"][sel])
    np.testing.assert_allclose(out["prob"], want, atol=2e-6)
    # points of the tower core get probability > 0; combine rules differ on overlaps
    assert (out["prob"] > 0.5).sum() > 100


def test_max_and_mean_differ_only_on_overlaps():
    tile = make_tile(density=0.3)
    o_max, _ = predict_tile(tile, FakeBundle(), grid_inference(combine="max"))
    o_mean, _ = predict_tile(tile, FakeBundle(), grid_inference(combine="mean"))
    np.testing.assert_array_equal(o_max["point_index"], o_mean["point_index"])
    assert (o_max["prob"] >= o_mean["prob"] - 1e-6).all()
    assert (o_max["prob"] > o_mean["prob"] + 1e-3).any()


def test_only_core_model_input_points_are_written(tmp_path):
    tile = make_tile()
    save_tile(tmp_path / "t.npz", tile)
    meta = infer_tile(tmp_path / "t.npz", FakeBundle(), tmp_path / "pred" / "p.npz", grid_inference())
    pred = load_pred(tmp_path / "pred" / "p.npz")
    a = tile.arrays
    key = {(int(b), int(p)): i for i, (b, p) in enumerate(zip(a["block_id"], a["point_index"]))}
    rows = np.array([key[(int(b), int(p))] for b, p in zip(pred["block_id"], pred["point_index"])])
    assert len(np.unique(rows)) == len(rows)
    assert a["core"][rows].all() and a["model_input"][rows].all()
    assert (pred["block_id"] == 0).all()  # the core lies in block b0
    np.testing.assert_array_equal(pred["x"], a["x"][rows])
    np.testing.assert_array_equal(pred["hag"], a["hag"][rows])
    # contract meta
    for k in PRED_META_KEYS:
        assert k in pred.meta, k
    assert pred.meta["points_core"] == int(a["core"].sum())
    assert pred.meta["points_model_input_core"] == int((a["core"] & a["model_input"]).sum())
    assert pred.meta["model"]["name"] == "fake" and pred.meta["combine"] == "max"
    assert pred.meta["peak_rss_mb"] > 0 and "classify" in pred.meta["timings"]
    assert meta["windows_total"] == pred.meta["windows_total"]


def test_adjacent_tiles_give_identical_probabilities_on_shared_windows():
    """The same window seen from two tiles yields the same per-point result."""
    tile = make_tile(density=0.3)
    a = tile.arrays
    # a second tile owning the west half of the same points (same buffer context)
    west = a["x"] < 400080.0
    t_w = Tile(dict(a, core=a["core"] & west), dict(tile.meta, tile="tw"))
    t_e = Tile(dict(a, core=a["core"] & ~west), dict(tile.meta, tile="te"))
    o_all, _ = predict_tile(tile, FakeBundle(), grid_inference())
    o_w, _ = predict_tile(t_w, FakeBundle(), grid_inference())
    o_e, _ = predict_tile(t_e, FakeBundle(), grid_inference())
    merged = {k: np.concatenate([o_w[k], o_e[k]]) for k in o_all}
    for k in ("point_index", "prob"):
        np.testing.assert_array_equal(by_id(merged)[k], by_id(o_all)[k])


# ----------------------------------------------------------------------------- determinism, batching


def test_deterministic_order_and_batch_independent():
    tile = make_tile(density=0.3)
    ref, st_ref = predict_tile(tile, FakeBundle(), grid_inference(batch_size=32), seed=5)
    again, _ = predict_tile(tile, FakeBundle(), grid_inference(batch_size=32), seed=5)
    one, _ = predict_tile(tile, FakeBundle(), grid_inference(batch_size=1), seed=5)
    for k in ref:
        np.testing.assert_array_equal(ref[k], again[k])
        np.testing.assert_array_equal(ref[k], one[k])
    # same points stored in another order: same result per point
    perm = np.random.default_rng(2).permutation(len(tile))
    shuffled, st_sh = predict_tile(tile.subset(perm), FakeBundle(), grid_inference(), seed=5)
    assert st_sh["window_probs"] == st_ref["window_probs"]
    for k in ref:
        np.testing.assert_array_equal(by_id(ref)[k], by_id(shuffled)[k])


def test_seed_changes_sampling():
    tile = make_tile(density=0.6)
    _, s0 = predict_tile(tile, FakeBundle(n_points=64), grid_inference(), seed=0)
    _, s1 = predict_tile(tile, FakeBundle(n_points=64), grid_inference(), seed=1)
    assert [k[:2] for k in s0["window_probs"]] == [k[:2] for k in s1["window_probs"]]
    assert [k[2] for k in s0["window_probs"]] != [k[2] for k in s1["window_probs"]]


# ----------------------------------------------------------------------------- compatibility, config


def test_check_model_compatibility_names_missing_attributes():
    class Full(FakeBundle):
        feature_set = "full"
        name = "towerpipe-full"

    meta = {"tile": "t0", "block": "b0", "valid_attributes": ["intensity", "returns", "rgb"]}
    with pytest.raises(ModelError, match=r"no valid nir.*model: auto"):
        check_model_compatibility(meta, Full())
    with pytest.raises(ModelError, match=r"no valid intensity, nir, rgb"):
        check_model_compatibility(dict(meta, valid_attributes=["returns"]), Full())
    check_model_compatibility(dict(meta, valid_attributes=["intensity", "returns", "rgb", "nir"]), Full())
    check_model_compatibility(dict(meta, valid_attributes=["intensity", "returns"]), FakeBundle())
    with pytest.raises(ModelError, match="no valid intensity, returns"):
        check_model_compatibility(dict(meta, valid_attributes=["rgb"]), FakeBundle())
    with pytest.raises(ModelError):
        predict_tile(make_tile(density=0.1), Full(), grid_inference())


# ----------------------------------------------------------------------------- candidate windows


def tower_points(tile: Tile) -> np.ndarray:
    a = tile.arrays
    return np.flatnonzero(
        a["core"] & a["model_input"] & (np.hypot(a["x"] - TOWER[0], a["y"] - TOWER[1]) < 3) & (a["hag"] > 0.4)
    )


def test_candidate_window_is_centred_on_the_tower():
    tile = make_tile()
    out, st = predict_tile(tile, FakeBundle(), grid_inference(windows="candidates", min_height=10.0))
    assert st["windows_mode"] == "candidates"
    assert st["windows_passed_gate"] == 1 and len(st["window_probs"]) == 1
    _, grid = predict_tile(tile, FakeBundle(), grid_inference(windows="grid", min_height=10.0))
    # the vegetation is low: the tower's top is the only candidate, where the grid classifies many windows
    assert st["windows_classified"] == 1 < grid["windows_classified"]


def test_candidate_windows_cover_every_tower_point_the_grid_segments():
    """When a tower is present, every one of its points that the grid mode segments is segmented."""
    for seed in range(3):
        tile = make_tile(seed=seed)
        grid, _ = predict_tile(tile, FakeBundle(), grid_inference(windows="grid", min_height=10.0))
        cand, _ = predict_tile(tile, FakeBundle(), grid_inference(windows="candidates", min_height=10.0))
        a = tile.arrays
        tower = set(zip(a["block_id"][tower_points(tile)].tolist(), a["point_index"][tower_points(tile)].tolist()))
        seg_grid = set(zip(grid["block_id"].tolist(), grid["point_index"].tolist())) & tower
        seg_cand = set(zip(cand["block_id"].tolist(), cand["point_index"].tolist()))
        assert seg_grid and seg_grid <= seg_cand


class ConstVerifier:
    """A shape verifier giving every object the same score."""

    name = "const"

    def __init__(self, score: float):
        self.value = score

    def score_descriptors(self, desc):
        return np.full(len(desc), self.value)


def test_shape_gate_skips_windows_whose_peak_object_it_rejects():
    tile = make_tile()
    settings = grid_inference(windows="candidates", min_height=10.0, shape_gate=0.05)
    ref, st_ref = predict_tile(tile, FakeBundle(), settings)  # no verifier: no shape gate
    assert st_ref["windows_shape_gated"] == 0 and st_ref["shape_gate"] is None
    kept, st_kept = predict_tile(tile, FakeBundle(), settings, verifier=ConstVerifier(1.0))
    assert st_kept["windows_shape_gated"] == 0 and st_kept["shape_gate"] == 0.05
    assert_same(kept, ref)
    none, st_none = predict_tile(tile, FakeBundle(), settings, verifier=ConstVerifier(0.0))
    assert st_none["windows_shape_gated"] == st_none["windows_total"] > 0
    assert st_none["windows_classified"] == 0 and len(none["x"]) == 0
    off, st_off = predict_tile(tile, FakeBundle(), replace(settings, shape_gate=0.0), verifier=ConstVerifier(0.0))
    assert st_off["windows_shape_gated"] == 0
    assert_same(off, ref)
    # the grid's windows have no peak: the shape gate does not apply
    grid = grid_inference(min_height=10.0, shape_gate=0.05)
    _, st_grid = predict_tile(tile, FakeBundle(), grid, verifier=ConstVerifier(0.0))
    assert st_grid["windows_shape_gated"] == 0 and st_grid["windows_classified"] > 0


def test_a_peak_object_the_verifier_is_sure_of_passes_the_classifier_gate():
    """``inference.shape_pass``: with the classifier's gate over every window (1.0), no window is
    segmented, but those whose peak object scores ``shape_pass`` or more are, as with no gate."""
    tile = make_tile()
    base = grid_inference(windows="candidates", min_height=10.0, shape_gate=0.05)
    open_gate, _ = predict_tile(tile, FakeBundle(), replace(base, gate=0.0), verifier=ConstVerifier(0.9))
    shut, st_shut = predict_tile(tile, FakeBundle(), replace(base, gate=1.0), verifier=ConstVerifier(0.9))
    assert st_shut["windows_segmented"] == 0 and len(shut["x"]) == 0
    sure, st_sure = predict_tile(
        tile, FakeBundle(), replace(base, gate=1.0, shape_pass=0.9), verifier=ConstVerifier(0.9)
    )
    assert st_sure["windows_segmented"] == st_sure["windows_classified"] > 0
    assert_same(sure, open_gate)
    unsure = replace(base, gate=1.0, shape_pass=0.95)
    assert predict_tile(tile, FakeBundle(), unsure, verifier=ConstVerifier(0.9))[1]["windows_segmented"] == 0


def test_windows_neither_gate_sees_a_tower_in_are_not_segmented():
    """``inference.gate_sure`` / ``unsure_shape``: a window the classifier passes but is unsure of
    (under ``gate_sure``) is segmented only if the shape gate scored its peak object
    ``unsure_shape`` or more; one it is sure of, whatever its shape score."""
    tile = make_tile()
    base = grid_inference(windows="candidates", min_height=10.0, shape_gate=0.05, gate=0.05)
    off, st_off = predict_tile(tile, FakeBundle(), replace(base, unsure_shape=0.0), verifier=ConstVerifier(0.3))
    assert st_off["windows_segmented"] > 0 and st_off["unsure_shape"] == 0.0
    best = max(p for p in st_off["window_gates"]["prob"] if p is not None)
    # every window unsure (gate_sure over the best probability) and scored 0.3: none segmented
    unsure = replace(base, gate_sure=min(1.0, best + 0.01), unsure_shape=0.5)
    cut, st_cut = predict_tile(tile, FakeBundle(), unsure, verifier=ConstVerifier(0.3))
    assert st_cut["windows_classified"] == st_off["windows_classified"]
    assert st_cut["windows_segmented"] == 0 and len(cut["x"]) == 0 and not any(st_cut["window_gates"]["segmented"])
    # scored at least unsure_shape: segmented, as with the condition off
    seen, _ = predict_tile(tile, FakeBundle(), unsure, verifier=ConstVerifier(0.5))
    same, _ = predict_tile(tile, FakeBundle(), replace(base, unsure_shape=0.0), verifier=ConstVerifier(0.5))
    assert_same(seen, same)
    # sure (gate_sure under the windows' probabilities): segmented whatever the shape score
    sure, st_sure = predict_tile(
        tile, FakeBundle(), replace(base, gate_sure=0.06, unsure_shape=0.5), verifier=ConstVerifier(0.3)
    )
    assert st_sure["windows_segmented"] == st_off["windows_segmented"]
    assert_same(sure, off)


def test_the_gates_record_of_each_window_what_they_made_of_it():
    """``window_gates`` (for ``towerpipe trace``): one entry per window that reached the gates,
    its shape score where the shape gate judged it, its probability where the classifier did."""
    tile = make_tile()
    settings = grid_inference(windows="candidates", min_height=10.0, shape_gate=0.05)
    _, st = predict_tile(tile, FakeBundle(), settings, verifier=ConstVerifier(1.0))
    g = st["window_gates"]
    n = st["windows_total"] - st["windows_prefiltered"]
    assert n > 0 and all(len(g[k]) == n for k in ("x", "y", "shape", "prob", "segmented"))
    assert g["shape"] == [1.0] * n and None not in g["prob"]
    assert sum(g["segmented"]) == st["windows_segmented"]
    assert all(p >= st["gate_threshold"] for p, s in zip(g["prob"], g["segmented"]) if s)
    # refused by the shape gate: never classified
    _, st_none = predict_tile(tile, FakeBundle(), settings, verifier=ConstVerifier(0.0))
    assert st_none["window_gates"]["shape"] == [0.0] * n and st_none["window_gates"]["prob"] == [None] * n
    assert not any(st_none["window_gates"]["segmented"])
    # no verifier: no shape score; the windows' centres are where the tile's windows are
    _, st_ref = predict_tile(tile, FakeBundle(), settings)
    assert st_ref["window_gates"]["shape"] == [None] * n
    assert st_ref["window_gates"]["x"] == g["x"] and st_ref["window_gates"]["y"] == g["y"]


def test_window_gates_are_plain_json_columns():
    import json

    from towerpipe.inference.windows import window_gates

    g = window_gates(
        np.array([[400000.04, 4600000.06], [400010.0, 4600010.0]]),
        np.array([0.123456, np.nan]),
        np.array([np.nan, 0.5]),
        np.array([False, True]),
    )
    assert g == {
        "x": [400000.0, 400010.0],
        "y": [4600000.1, 4600010.0],
        "shape": [0.1235, None],
        "prob": [None, 0.5],
        "segmented": [False, True],
    }
    assert json.loads(json.dumps(g)) == g
    assert window_gates(np.empty((0, 2)), np.empty(0), np.empty(0), np.empty(0, bool))["x"] == []


def test_candidate_windows_identical_from_adjacent_tiles():
    tile = make_tile(density=0.3)
    a = tile.arrays
    west = a["x"] < 400080.0
    t_w = Tile(dict(a, core=a["core"] & west), dict(tile.meta, tile="tw"))
    t_e = Tile(dict(a, core=a["core"] & ~west), dict(tile.meta, tile="te"))
    kw = dict(windows="candidates", min_height=10.0)
    o_all, _ = predict_tile(tile, FakeBundle(), grid_inference(**kw))
    merged = [predict_tile(t, FakeBundle(), grid_inference(**kw))[0] for t in (t_w, t_e)]
    merged = {k: np.concatenate([m[k] for m in merged]) for k in o_all}
    for k in ("point_index", "prob"):
        np.testing.assert_array_equal(by_id(merged)[k], by_id(o_all)[k])


def test_bad_config_rejected():
    """Settings built by hand (not from a validated config) are checked too."""
    tile = make_tile(density=0.1)
    with pytest.raises(ConfigError):
        predict_tile(tile, FakeBundle(), replace(grid_inference(), combine="median"))
    with pytest.raises(ConfigError):
        predict_tile(tile, FakeBundle(), replace(grid_inference(), gate=1.5))
    with pytest.raises(ConfigError, match="inference.windows"):
        predict_tile(tile, FakeBundle(), replace(grid_inference(), windows="hexagons"))


# ----------------------------------------------------------------------------- the real model


def test_random_initialised_real_bundle_runs(tmp_path):
    torch = pytest.importorskip("torch")
    model = pytest.importorskip("towerpipe.model.pointnet")
    bundles = pytest.importorskip("towerpipe.model.bundle")
    torch.manual_seed(0)
    c = len(features.FEATURE_SETS["geometry"])
    bundle = bundles.ModelBundle(
        name="random",
        version="0",
        feature_set="geometry",
        card={},
        n_points=2048,
        classifier=model.PointNetClassifier(c),
        segmenter=model.PointNetSegmenter(c),
    )
    tile = make_tile(density=0.1)
    save_tile(tmp_path / "t.npz", tile)
    kw = dict(gate=0.0, stride=40.0)  # 25 windows, all segmented: keeps the CPU test short
    m1 = infer_tile(tmp_path / "t.npz", bundle, tmp_path / "p1.npz", grid_inference(**kw))
    m2 = infer_tile(tmp_path / "t.npz", bundle, tmp_path / "p2.npz", grid_inference(batch_size=7, **kw))
    p1, p2 = load_pred(tmp_path / "p1.npz"), load_pred(tmp_path / "p2.npz")
    assert m1["windows_segmented"] == m1["windows_total"] > 0
    assert len(p1) == m1["points_model_input_core"]  # gate 0: every core model-input point is written
    assert ((p1["prob"] >= 0) & (p1["prob"] <= 1)).all()
    np.testing.assert_array_equal(p1["point_index"], p2["point_index"])
    np.testing.assert_allclose(p1["prob"], p2["prob"], atol=1e-5)
    assert m2["windows_total"] == m1["windows_total"]


def test_a_tile_with_nothing_tall_never_loads_the_networks(tmp_path, random_model_factory):
    from towerpipe.model.bundle import load_bundle
    from towerpipe.model.lazy import LazyBundle

    path = random_model_factory("shape")
    save_tile(tmp_path / "flat.npz", make_tile(tower=None))
    lazy = LazyBundle(path)
    meta = infer_tile(tmp_path / "flat.npz", lazy, tmp_path / "flat_p.npz", inference_settings())
    assert not lazy.loaded and len(load_pred(tmp_path / "flat_p.npz")) == 0
    assert meta["model"]["name"] == lazy.card["name"] and meta["windows_total"] == 0

    # a tile with a tower loads them on its first window, with the same result as a loaded bundle
    save_tile(tmp_path / "tall.npz", make_tile())
    lazy = LazyBundle(path)
    infer_tile(tmp_path / "tall.npz", lazy, tmp_path / "lazy_p.npz", inference_settings())
    infer_tile(tmp_path / "tall.npz", load_bundle(path), tmp_path / "eager_p.npz", inference_settings())
    infer_tile(tmp_path / "tall.npz", path, tmp_path / "path_p.npz", inference_settings())
    assert lazy.loaded
    eager = load_pred(tmp_path / "eager_p.npz")
    for other in ("lazy_p.npz", "path_p.npz"):
        got = load_pred(tmp_path / other)
        for k in eager.arrays:
            np.testing.assert_array_equal(got.arrays[k], eager.arrays[k])


class CentreColumn(FakeBundle):
    """Says "tower" for a window whose centre holds points 12-17 m high and nothing higher,
    and paints every tall point of a window it segments."""

    def classify(self, feats: np.ndarray) -> np.ndarray:
        out = np.zeros(feats.shape[0], dtype=np.float32)
        for b, f in enumerate(feats):
            xy, z = f[:, :2] * R, f[:, 2] * R
            centre = np.abs(xy).max(axis=1) < 2.0
            out[b] = 0.9 if (centre & (z > 12)).sum() >= 5 and z[centre].max() < 17.0 else 0.0
        return out

    def segment(self, feats: np.ndarray) -> np.ndarray:
        return np.where(feats[:, 2] * R > 5.0, 0.9, 0.0).astype(np.float32)


def tile_with_hidden_tower(seed: int = 3, two_tops: bool = False) -> Tile:
    """A 16 m column at TOWER among 19 m crowns 11 m away: no peak of its own within 10 m.
    ``two_tops``: also a 30 m tower 60 m east with a 27 m crossarm end 8.5 m from its top (a peak
    within 7 m, not within 10 m)."""
    tile = make_tile(seed, tower=None, density=0.2)
    rng = np.random.default_rng(seed)
    obj = tower_among_crowns(TOWER, seed)
    if two_tops:
        tx, ty = TOWER[0] + 60.0, TOWER[1]
        body = np.c_[tx + rng.uniform(-1, 1, 300), ty + rng.uniform(-1, 1, 300), rng.uniform(0.5, 30.0, 300)]
        arm = np.c_[tx + 8.5 + rng.uniform(-0.3, 0.3, 40), ty + rng.uniform(-0.3, 0.3, 40), rng.uniform(25.0, 27.0, 40)]
        obj = np.concatenate([obj, body, arm])
    return tile_with_points(tile, obj)


def tile_with_points(tile: Tile, obj: np.ndarray) -> Tile:
    """``tile`` with the points ``obj`` (x, y, height) added: core, model input, class 1."""
    a = tile.arrays
    n0, k = len(a["x"]), len(obj)
    new = empty_arrays(k)
    new["x"], new["y"], new["hag"] = obj[:, 0], obj[:, 1], obj[:, 2].astype(np.float32)
    new["z"] = 200.0 + obj[:, 2]
    new["classification"] = np.ones(k, np.uint8)
    new["point_index"] = np.arange(n0, n0 + k, dtype=np.int64)
    new["core"] = np.ones(k, bool)
    new["model_input"] = np.ones(k, bool)
    merged = {key: np.concatenate([a[key], new[key]]) for key in a}
    return Tile(merged, tile.meta)


def test_secondary_peaks_reach_a_hidden_tower_and_paint_only_near_it():
    """A tower among higher crowns is found only through its secondary peak; that window sets
    the probabilities within secondary_reach of its centre only; a secondary peak within
    PEAK_RADIUS of a segmented primary peak is not segmented."""
    tile = tile_with_hidden_tower()
    base = grid_inference(windows="candidates", min_height=10.0, gate=0.5, secondary_radius=0.0)
    off, st_off = predict_tile(tile, CentreColumn(), base)
    assert st_off["windows_segmented"] == 0 and len(off["x"]) == 0
    on, st_on = predict_tile(tile, CentreColumn(), replace(base, secondary_radius=7.0, secondary_reach=4.0))
    assert st_on["windows_segmented"] == 1
    d = np.hypot(on["x"] - TOWER[0], on["y"] - TOWER[1])
    assert len(d) and d.max() <= 4.0 + 1.6  # the window's centre is the column's top cell
    assert on["prob_single"].max() == np.float32(0.9)
    # a classifier that passes every window: the crossarm end, 8.5 m from its tower's top, is not
    # segmented; the hidden column, 11 m from the crowns' tops, is
    both = tile_with_hidden_tower(two_tops=True)
    _, st_all = predict_tile(both, FakeBundle(), replace(base, gate=0.0, secondary_radius=7.0, secondary_reach=4.0))
    _, st_prim = predict_tile(both, FakeBundle(), replace(base, gate=0.0))
    assert st_all["windows_total"] == st_prim["windows_total"] + 2
    assert st_all["windows_segmented"] == st_prim["windows_segmented"] + 1


class CentreFirst(FakeBundle):
    """Paints a window's tall points the more surely the nearer they are to its centre (what the
    networks do: they read a window's centre as the tower's place)."""

    def segment(self, feats: np.ndarray) -> np.ndarray:
        d = np.hypot(feats[:, 0], feats[:, 1]) * R
        return np.where(feats[:, 2] * R > 5.0, np.clip(0.9 - d / 40.0, 0.0, 1.0), 0.0).astype(np.float32)


def test_the_lower_tower_of_a_pair_is_segmented_beside_its_neighbour_only():
    """A stem window (the lower tower of a pair, under its neighbour's crossarms) skips the
    classifier, is segmented when a segmented peak window lies within half a window, and sets the
    probabilities within stem_reach of its centre only; with no peak window segmented, neither is it."""
    lower = (TOWER[0] + 10.5, TOWER[1])
    tile = tile_with_points(make_tile(5, tower=None, density=0.2), towers_side_by_side(TOWER))
    base = grid_inference(windows="candidates", min_height=10.0, gate=0.0, secondary_radius=0.0)
    off, st_off = predict_tile(tile, CentreFirst(), base)
    on, st_on = predict_tile(tile, CentreFirst(), replace(base, stem_gap=8.0, stem_reach=5.0))
    assert st_on["windows_total"] == st_off["windows_total"] + 1
    assert st_on["windows_classified"] == st_off["windows_classified"]  # the stem is not classified
    assert st_on["windows_shape_gated"] == st_off["windows_shape_gated"] == 0
    assert st_on["windows_segmented"] == st_off["windows_segmented"] + 1
    assert st_on["window_probs"] == st_off["window_probs"]  # the classifier's windows only
    # the neighbour's window covers the lower tower; the stem window changes only what is near its centre
    assert np.array_equal(on["point_index"], off["point_index"])
    changed = on["prob_single"] != off["prob_single"]
    assert changed.sum() > 100 and (on["prob_single"] >= off["prob_single"]).all()
    assert np.hypot(on["x"][changed] - lower[0], on["y"][changed] - lower[1]).max() <= 5.0 + 1.5

    # a classifier that passes no window: no peak window is segmented, and no stem window either
    class NoTower(CentreFirst):
        def classify(self, feats: np.ndarray) -> np.ndarray:
            return np.zeros(feats.shape[0], np.float32)

    _, st_none = predict_tile(tile, NoTower(), replace(base, gate=0.5, stem_gap=8.0, stem_reach=5.0))
    assert st_none["windows_segmented"] == 0


def tile_with_wire(classified: bool) -> Tile:
    """:func:`make_tile` with a conductor 25 m up passing 6 m from the tower (one point every
    0.25 m), classified as wire (14) or not (1, a delivery without a wire class)."""
    tile = make_tile()
    a = dict(tile.arrays)
    xs = np.arange(CORE[0] - 30.0, CORE[2] + 30.0, 0.25)
    n = len(xs)
    w = empty_arrays(n)
    w["x"], w["y"] = xs, np.full(n, TOWER[1] + 6.0)
    w["hag"] = np.full(n, 25.0, np.float32)
    w["z"] = 225.0 + 0.01 * (xs - CORE[0])
    w["intensity"] = np.full(n, 1000, np.uint16)
    w["return_number"], w["number_of_returns"] = np.ones(n, np.uint8), np.ones(n, np.uint8)
    w["classification"] = np.full(n, 14 if classified else 1, np.uint8)
    w["block_id"] = np.where(xs >= CORE[2], 1, 0).astype(np.int32)
    w["point_index"] = np.arange(n, dtype=np.int64) + 10_000_000
    w["core"] = (xs >= CORE[0]) & (xs < CORE[2])
    w["model_input"] = np.ones(n, bool)
    return Tile({k: np.concatenate([a[k], w[k]]) for k in a}, tile.meta)


def test_wires_are_never_tower_whether_classified_or_detected():
    """The points the delivery classifies as wire have probability 0; a tile without a wire class
    takes the wire detector's instead. The tower keeps its points either way."""
    settings = grid_inference(windows="candidates", min_height=10.0, gate=0.05)  # the fake gate doubts the window
    for classified in (True, False):
        tile = tile_with_wire(classified)
        out, st = predict_tile(tile, FakeBundle(), settings)
        assert st["wire_source"] == ("classified" if classified else "detected")
        wire = out["point_index"] >= 10_000_000
        assert wire.sum() > 20 and (out["prob"][wire] == 0).all() and (out["prob_single"][wire] == 0).all()
        tower = np.hypot(out["x"] - TOWER[0], out["y"] - TOWER[1]) < 3
        assert (out["prob"][tower & (out["hag"] > 10)] > 0.3).all()
    # the rule is what takes them: the fake segmenter paints every tall point
    painted = fake_segment(np.zeros(1, np.float32), np.full(1, 25.0 / R, np.float32))
    assert painted[0] > 0.3


def test_a_model_reading_the_local_structure_is_order_and_tile_independent(random_model_factory):
    """The local structure is computed among each window's points in canonical order: the same
    per-point result for any storage order, and for a window seen from two tiles."""
    from towerpipe.model.bundle import load_bundle

    bundle = load_bundle(random_model_factory("structure"))
    tile = make_tile(density=0.3)
    settings = grid_inference(gate=0.0)
    ref, st = predict_tile(tile, bundle, settings, seed=5)
    assert st["windows_segmented"] > 0 and len(ref["prob"]) > 0
    perm = np.random.default_rng(4).permutation(len(tile))
    shuffled, st_sh = predict_tile(tile.subset(perm), bundle, settings, seed=5)
    assert st_sh["window_probs"] == st["window_probs"]
    for k in ref:
        np.testing.assert_allclose(by_id(ref)[k], by_id(shuffled)[k], atol=1e-6)
