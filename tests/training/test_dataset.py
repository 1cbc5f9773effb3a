"""Window building from labelled tile files: towers, positives/negatives, block split."""

from __future__ import annotations

import numpy as np
import pytest

from towerpipe.errors import ConfigError
from towerpipe.io.tiles import Tile, empty_arrays, save_tile
from towerpipe.training.dataset import build_windows, split_blocks, tall_objects, tower_instances
from towerpipe.training.windowset import KINDS, SPLITS, load_windows


def make_tile(
    path,
    block: str,
    origin: tuple[float, float],
    towers: list[tuple[float, float]],
    seed: int = 0,
    n_veg: int = 6000,
    size: float = 100.0,
    tower_pts: int = 400,
) -> Tile:
    """A tiny labelled tile: scattered vegetation plus lattice-tower columns of class 15."""
    rng = np.random.default_rng(seed)
    ox, oy = origin
    # vegetation: clustered shrubs and trees, HAG 0.5-18 m, green, high NIR
    vx = rng.uniform(ox - 20, ox + size + 20, n_veg)
    vy = rng.uniform(oy - 20, oy + size + 20, n_veg)
    vh = np.abs(rng.gamma(2.0, 2.5, n_veg)) + 0.3
    parts = [
        dict(
            x=vx,
            y=vy,
            h=vh,
            cls=np.where(vh < 3, 3, np.where(vh < 8, 4, 5)),
            rgb=(60, 120, 50),
            nir=200,
            inten=rng.normal(60, 15, n_veg),
            nret=rng.integers(1, 4, n_veg),
        )
    ]
    for tx, ty in towers:
        h = rng.uniform(0, 25, tower_pts)
        half = 3.0 * (1 - h / 35)  # legs converge with height
        leg = rng.integers(0, 4, tower_pts)
        sx = np.where(leg % 2 == 0, -1, 1) * half
        sy = np.where(leg < 2, -1, 1) * half
        along = rng.uniform(-1, 1, tower_pts) * half * (rng.random(tower_pts) < 0.3)  # cross bars
        x = tx + sx + np.where(leg < 2, along, 0)
        y = ty + sy + np.where(leg >= 2, along, 0)
        parts.append(
            dict(
                x=x,
                y=y,
                h=h,
                cls=np.full(tower_pts, 15),
                rgb=(140, 140, 140),
                nir=120,
                inten=rng.normal(150, 20, tower_pts),
                nret=np.ones(tower_pts, int),
            )
        )
    n = sum(len(p["x"]) for p in parts)
    a = empty_arrays(n)
    s = 0
    for p in parts:
        e = s + len(p["x"])
        a["x"][s:e], a["y"][s:e] = p["x"], p["y"]
        a["hag"][s:e] = p["h"]
        a["z"][s:e] = 100.0 + p["h"]
        a["classification"][s:e] = p["cls"]
        a["red"][s:e], a["green"][s:e], a["blue"][s:e] = p["rgb"]
        a["nir"][s:e] = p["nir"]
        a["intensity"][s:e] = np.clip(p["inten"], 1, 65535)
        a["number_of_returns"][s:e] = p["nret"]
        a["return_number"][s:e] = 1
        s = e
    a["point_index"] = np.arange(n)
    a["model_input"][:] = True
    a["core"] = (a["x"] >= ox) & (a["x"] < ox + size) & (a["y"] >= oy) & (a["y"] < oy + size)
    meta = {
        "zone": "t",
        "block": block,
        "tile": f"{block}_0",
        "blocks": [block],
        "crs_wkt": "",
        "core_bounds": [ox, oy, ox + size, oy + size],
        "buffer": 20.0,
        "has_rgb": True,
        "has_nir": True,
        "color_bits": 8,
        "ground_source": "class2",
        "counts": {},
    }
    tile = Tile(a, meta)
    save_tile(path, tile)
    return tile


def make_tiles(tmp_path, n_blocks: int = 5, seed: int = 0, **kw) -> list[str]:
    """``n_blocks`` single-tile blocks, each with two towers."""
    paths = []
    for b in range(n_blocks):
        ox = 1000.0 * b
        p = tmp_path / f"b{b}" / f"b{b}_0.npz"
        make_tile(p, f"b{b}", (ox, 0.0), [(ox + 30, 30), (ox + 70, 65)], seed=seed + b, **kw)
        paths.append(str(p))
    return paths


def test_tower_instances_link_and_min_points():
    rng = np.random.default_rng(1)
    a = rng.normal(0, 0.5, (30, 3))
    b = rng.normal(0, 0.5, (10, 3)) + [50, 0, 0]  # too small
    c = rng.normal(0, 0.5, (25, 3)) + [0, 40, 0]
    comps = tower_instances(np.vstack([a, b, c]), 2.5, 20)
    assert sorted(len(x) for x in comps) == [25, 30]


def test_tall_objects_group_cells_and_sort_by_height():
    rng = np.random.default_rng(2)
    tree = np.c_[rng.normal(0, 1.5, (60, 2))]  # a crown, 12-16 m
    mast = np.c_[rng.normal(0, 0.3, (40, 2))] + [40, 0]  # a mast, up to 45 m
    wire = np.c_[np.linspace(-30, 30, 200), np.full(200, 25.0)]  # one long object
    xy = np.vstack([tree, mast, wire])
    hag = np.r_[rng.uniform(12, 16, 60), np.linspace(10, 45, 40), np.full(200, 20.0)]
    objs = tall_objects(xy, hag, 2.0)
    assert len(objs) == 3
    assert [round(h) for _, h in objs] == [45, 20, round(hag[:60].max())]
    np.testing.assert_allclose(objs[0][0], mast[np.argmax(hag[60:100])])
    assert tall_objects(np.zeros((0, 2)), np.zeros(0), 2.0) == []


def test_tallest_object_gets_a_negative_window(tmp_path):
    """A 45 m mast among 10-18 m trees always gets a tall negative window (not left to chance)."""
    p = tmp_path / "b0" / "b0_0.npz"
    tile = make_tile(p, "b0", (0.0, 0.0), [(30, 30)], seed=5)
    a = dict(tile.arrays)
    k = 300
    rng = np.random.default_rng(0)
    extra = {name: np.repeat(v[:1], k) for name, v in a.items()}
    extra["x"], extra["y"] = 80 + rng.normal(0, 0.4, k), 80 + rng.normal(0, 0.4, k)
    extra["hag"] = rng.uniform(0, 45, k)
    extra["z"] = 100 + extra["hag"]
    extra["classification"] = np.full(k, 1, a["classification"].dtype)
    merged = {name: np.concatenate([v, extra[name].astype(v.dtype)]) for name, v in a.items()}
    merged["point_index"] = np.arange(len(merged["x"]))
    from towerpipe.io.tiles import Tile, save_tile

    save_tile(p, Tile(merged, tile.meta))
    for seed in range(3):
        ws = build_windows(
            [str(p)], {"n_points": 128, "seed": seed, "tall_negatives_per_tile": 2, "split": {"val": [], "test": []}}
        )
        c = ws.center[ws.kind == KINDS["tall_negative"]]
        assert len(c) >= 1 and np.min(np.abs(c - [80, 80]).max(axis=1)) <= 5.0 + 1.5
        assert ws.meta["tall_objects"] >= 2


def test_build_windows_counts_and_labels(tmp_path):
    paths = make_tiles(tmp_path, 5)
    ws = build_windows(paths, {"n_points": 256, "seed": 3})
    assert ws.meta["towers"] == 10
    pos = ws.kind == KINDS["positive"]
    assert pos.sum() == 10 and (ws.kind == KINDS["positive_shifted"]).sum() == 10
    assert (ws.kind == KINDS["hard_negative"]).sum() == 20
    # positives carry the tower points, hard negatives none
    for i in np.flatnonzero(ws.label == 1):
        assert ws.point_label[ws.offsets[i] : ws.offsets[i + 1]].sum() >= 20
    for i in np.flatnonzero(ws.kind == KINDS["hard_negative"]):
        assert ws.point_label[ws.offsets[i] : ws.offsets[i + 1]].sum() == 0
        assert ws.label[i] == 0
    for i in np.flatnonzero(np.isin(ws.kind, [KINDS["random_negative"], KINDS["tall_negative"]])):
        assert ws.point_label[ws.offsets[i] : ws.offsets[i + 1]].sum() == 0
    assert (ws.kind == KINDS["tall_negative"]).sum() > 0
    x, lab = ws.sampled(np.arange(len(ws)), "full")
    assert x.shape == (len(ws), 256, 7) and lab.shape == (len(ws), 256)
    assert np.abs(x[..., :2]).max() <= 20 * np.sqrt(2) / 57.4 + 1e-2  # inside the window, unit-sphere scale
    # shifted positives are within 10 m of a tower centre (x/y each)
    unshifted = ws.center[pos]
    for c in ws.center[ws.kind == KINDS["positive_shifted"]]:
        assert np.min(np.max(np.abs(unshifted - c), axis=1)) <= 10.0
    # round trip
    p = ws.save(tmp_path / "w.npz")
    ws2 = load_windows(p)
    np.testing.assert_array_equal(ws2.feat, ws.feat)
    assert ws2.meta["split"] == ws.meta["split"]


def test_split_by_block_has_no_leakage(tmp_path):
    paths = make_tiles(tmp_path, 6)
    ws = build_windows(paths, {"n_points": 128, "seed": 0, "val_fraction": 0.2, "test_fraction": 0.2})
    per_block = {}
    for b, s in zip(ws.block_id, ws.split):
        per_block.setdefault(int(b), set()).add(int(s))
    assert all(len(s) == 1 for s in per_block.values()), per_block
    assert {SPLITS["train"], SPLITS["val"], SPLITS["test"]} <= set(ws.split.tolist())
    # windows of the same tower (positive, shifted, hard negatives) share a split
    assert set(ws.meta["split"].values()) == {"train", "val", "test"}


def test_split_blocks_rules():
    s = split_blocks({f"b{i}": i < 5 for i in range(9)}, 0.2, 0.2, seed=1)
    tower_splits = [s[f"b{i}"] for i in range(5)]
    assert tower_splits.count("val") >= 1 and tower_splits.count("test") >= 1 and tower_splits.count("train") >= 1
    assert s == split_blocks({f"b{i}": i < 5 for i in range(9)}, 0.2, 0.2, seed=1)
    with pytest.raises(ConfigError, match="3 blocks"):
        split_blocks({"a": True, "b": True}, 0.2, 0.2, seed=0)


def test_pinned_split_is_used_and_checked(tmp_path):
    paths = make_tiles(tmp_path, 4)
    ws = build_windows(paths, {"n_points": 64, "seed": 0, "split": {"val": ["b1"], "test": ["b3"]}})
    assert ws.meta["split"] == {"b0": "train", "b1": "val", "b2": "train", "b3": "test"}
    # YAML reads an unquoted 400000_4600800 as a number: a name that matches no block is an error
    with pytest.raises(ConfigError, match="quote block names"):
        build_windows(paths, {"n_points": 64, "split": {"val": [4000004600800], "test": ["b3"]}})


def test_windows_thinned_to_their_own_density(tmp_path):
    """Each window has a density of its own, from the range; a positive keeps enough tower points."""
    paths = make_tiles(tmp_path, n_blocks=3, tower_pts=800)
    full = build_windows(paths, {"val_fraction": 0.34, "test_fraction": 0.34, "seed": 3})
    thin = build_windows(
        paths,
        {"val_fraction": 0.34, "test_fraction": 0.34, "seed": 3, "density_range": [0.05, 0.2], "positive_shifts": 3},
    )
    pos_full = [np.diff(full.offsets)[i] for i in np.flatnonzero(full.label == 1)]
    pos_thin = [np.diff(thin.offsets)[i] for i in np.flatnonzero(thin.label == 1)]
    assert np.median(pos_thin) < 0.5 * np.median(pos_full)
    assert len(set(pos_thin)) > len(pos_thin) // 2  # densities differ window to window
    tower_pts = [int(thin.point_label[thin.offsets[i] : thin.offsets[i + 1]].sum()) for i in np.flatnonzero(thin.label)]
    assert min(tower_pts) >= 20
    # three shifted copies per tower on top of the centred one
    assert (thin.kind == KINDS["positive_shifted"]).sum() == 3 * (thin.kind == KINDS["positive"]).sum()


def test_occlusion_takes_a_face_of_the_tower(tmp_path):
    paths = make_tiles(tmp_path, n_blocks=3, tower_pts=800)
    cfg = {"val_fraction": 0.34, "test_fraction": 0.34, "seed": 5, "positive_shifts": 0}
    plain = build_windows(paths, cfg)
    occl = build_windows(paths, {**cfg, "occlusion": 1.0})
    t0 = [int(plain.point_label[plain.offsets[i] : plain.offsets[i + 1]].sum()) for i in np.flatnonzero(plain.label)]
    t1 = [int(occl.point_label[occl.offsets[i] : occl.offsets[i + 1]].sum()) for i in np.flatnonzero(occl.label)]
    assert len(t0) == len(t1) and all(b < a for a, b in zip(t0, t1))
    assert np.median(np.array(t1) / np.array(t0)) < 0.8


def test_tower_thinning_thins_the_tower_alone(tmp_path):
    """The tower's points get sparser, the rest of the window stays; never under min_tower_points + 10."""
    paths = make_tiles(tmp_path, n_blocks=3, tower_pts=800)
    cfg = {"val_fraction": 0.34, "test_fraction": 0.34, "seed": 5, "positive_shifts": 0}
    plain = build_windows(paths, cfg)
    thin = build_windows(paths, {**cfg, "tower_thinning": {"probability": 1.0, "keep": [0.01, 0.02]}})
    never = build_windows(paths, {**cfg, "tower_thinning": {"probability": 0.0, "keep": [0.01, 0.02]}})

    def counts(ws):
        pos = np.flatnonzero(ws.kind == KINDS["positive"])
        lab = [ws.point_label[ws.offsets[i] : ws.offsets[i + 1]] for i in pos]
        return np.array([int(v.sum()) for v in lab]), np.array([int((v == 0).sum()) for v in lab])

    (t0, b0), (t1, b1), (t2, b2) = counts(plain), counts(thin), counts(never)
    assert len(t0) == len(t1) and (t1 < t0).all() and t1.min() >= 30
    assert np.array_equal(b0, b1)  # the window around the tower is untouched
    assert np.array_equal(t0, t2) and np.array_equal(b0, b2)


def test_windows_know_their_tower_family(tmp_path):
    """With the truth, every window records the families of its towers; a hard negative, its lost tower's."""
    import geopandas as gpd
    import shapely

    from towerpipe.training.windowset import FAMILY_BITS

    paths = make_tiles(tmp_path, n_blocks=3)
    rows = []
    for b in range(3):
        ox = 1000.0 * b
        rows += [
            {"design": "real:uav:001Tower", "x": ox + 30, "y": 30.0, "geometry": shapely.Point(ox + 30, 30)},
            {"design": "lattice_waist", "x": ox + 70, "y": 65.0, "geometry": shapely.Point(ox + 70, 65)},
        ]
    truth = tmp_path / "truth.gpkg"
    gpd.GeoDataFrame(rows, geometry="geometry", crs="EPSG:25831").to_file(truth, layer="towers")
    ws = build_windows(paths, {"val_fraction": 0.34, "test_fraction": 0.34, "positive_shifts": 0}, truth={"t": truth})
    pos = np.flatnonzero(ws.kind == KINDS["positive"])
    fams = {int(f) for f in ws.family[pos]}
    assert FAMILY_BITS["uav"] in {f & FAMILY_BITS["uav"] for f in fams}
    assert any(f & FAMILY_BITS["synthetic"] for f in fams)
    hard = np.flatnonzero(ws.kind == KINDS["hard_negative"])
    assert (ws.family[hard] > 0).all() and ws.label[hard].max() == 0
    assert (ws.family[ws.kind == KINDS["random_negative"]] == 0).all()
    out = ws.save(tmp_path / "w.npz")
    np.testing.assert_array_equal(load_windows(out).family, ws.family)
    assert (
        ws.meta["summary"]["train"]["positive_by_family"]["uav"]
        + ws.meta["summary"]["val"]["positive_by_family"]["uav"]
        + ws.meta["summary"]["test"]["positive_by_family"]["uav"]
        >= 3
    )


def test_stored_local_structure_is_that_among_all_the_window_points(tmp_path):
    """A negative window stores its two samples only; their local structure is still the one
    they have among all the window's points, as inference computes it."""
    from scipy.spatial import cKDTree

    from towerpipe.model.features import ALL_FEATURES, LOCAL_STRUCTURE, NORM_RADIUS, local_structure

    paths = make_tiles(tmp_path, 3)
    ws = build_windows(paths, {"n_points": 128, "seed": 1})
    cols = [ALL_FEATURES.index(c) for c in LOCAL_STRUCTURE]
    tile = np.load(paths[0])
    x, y, h = tile["x"], tile["y"], tile["hag"].astype(np.float64)
    neg = [i for i in np.flatnonzero(ws.kind == KINDS["random_negative"]) if 0 <= ws.center[i][0] < 1000.0]
    assert neg
    for i in neg[:3]:
        cx, cy = ws.center[i]
        inside = (np.abs(x - cx) <= 20.0) & (np.abs(y - cy) <= 20.0)
        whole = local_structure(x[inside] - cx, y[inside] - cy, h[inside])
        stored = ws.feat[ws.offsets[i] : ws.offsets[i + 1]].astype(np.float64)
        assert len(stored) < inside.sum()  # the samples, not the window
        xyz = np.c_[x[inside] - cx, y[inside] - cy, h[inside]] / NORM_RADIUS
        d, j = cKDTree(xyz).query(stored[:, :3])
        same = d < 1e-3
        assert same.mean() > 0.95
        np.testing.assert_allclose(stored[same][:, cols], whole[j[same]], atol=2e-3)
        own = local_structure(*(stored[:, :3] * NORM_RADIUS).T)
        assert np.abs(own - stored[:, cols]).max() > 0.05  # among the samples alone they differ
