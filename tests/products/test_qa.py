"""Tests of towerpipe.products.qa: block QA pages and the zone index."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import rasterio
import shapely
import shapely.affinity
from affine import Affine

from conftest import extract, qa_limits
from towerpipe import classes
from towerpipe.products.qa.block import BlockInputs, block_report
from towerpipe.products.qa.index import zone_index
from towerpipe.products.qa.metrics import label_accuracy, load_classified, read_benchmark

X0, Y0 = 400_000.0, 4_600_000.0
SIZE = 200.0
BOUNDS = (X0, Y0, X0 + SIZE, Y0 + SIZE)
MODEL = {"name": "pointnet_l", "version": "1.2.0", "feature_set": "full", "sha256": "cd" * 32}


def ground_z(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 100.0 + 0.05 * (x - X0) + 3.0 * np.sin((y - Y0) / 30.0)


def tower(cx: float, cy: float, height: float = 30.0, step: float = 0.4) -> np.ndarray:
    t = np.arange(0.0, height, step)
    half = 3.0 - 2.0 * t / height
    legs = [np.column_stack([cx + sx * half, cy + sy * half, t]) for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1))]
    a = np.arange(-6, 6.01, step)
    legs.append(np.column_stack([cx + a, np.full_like(a, cy), np.full_like(a, 0.8 * height)]))
    xyz = np.concatenate(legs)
    xyz[:, 2] += ground_z(xyz[:, 0], xyz[:, 1])
    return xyz


def make_block(seed: int = 0, towers_at=((X0 + 60, Y0 + 60), (X0 + 150, Y0 + 120)), density: float = 4.0):
    """Classified points of a small block: ground, trees, towers; a missed and a false tower part."""
    rng = np.random.default_rng(seed)
    n = int(density * SIZE * SIZE)
    gx, gy = rng.uniform(X0, X0 + SIZE, n), rng.uniform(Y0, Y0 + SIZE, n)
    ground = np.column_stack([gx, gy, ground_z(gx, gy)])
    vx, vy = rng.uniform(X0, X0 + SIZE, n // 4), rng.uniform(Y0, Y0 + SIZE, n // 4)
    veg = np.column_stack([vx, vy, ground_z(vx, vy) + rng.uniform(0.5, 12, n // 4)])
    tws = [tower(cx, cy) for cx, cy in towers_at]
    xyz = np.concatenate([ground, veg, *tws])
    cls = np.concatenate([np.full(n, 2), np.full(n // 4, 4), *[np.full(len(t), 15) for t in tws]]).astype(np.uint8)
    hag = (xyz[:, 2] - ground_z(xyz[:, 0], xyz[:, 1])).astype(np.float32)
    prob = np.where(cls == 15, 0.9, 0.02).astype(np.float32)
    return {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "classification": cls, "prob": prob, "hag": hag}


def towers_of(pts, block="b1"):
    sel = pts["prob"] >= 0.5
    n = int(sel.sum())
    arrays = {
        "block_id": np.zeros(n, np.int32),
        "point_index": np.flatnonzero(sel).astype(np.int64),
        **{k: pts[k][sel] for k in ("x", "y", "z", "hag", "prob")},
    }
    gdf = extract(
        [(arrays, {"blocks": [block], "crs_wkt": "EPSG:25831", "model": MODEL})], block, BOUNDS, zone="z1"
    ).towers
    gdf["wire_support"] = 1.0  # conductors found (unknown support is flagged)
    return gdf


def dtm_tif(path, res: float = 2.0):
    """The block's DTM as a GeoTIFF (100 x 100 cells of ``res`` m)."""
    xs = X0 + res * (np.arange(100) + 0.5)
    ys = Y0 + SIZE - res * (np.arange(100) + 0.5)
    profile = dict(driver="GTiff", width=100, height=100, count=1, dtype="float32", crs="EPSG:25831")
    with rasterio.open(path, "w", transform=Affine(res, 0.0, X0, 0.0, -res, Y0 + SIZE), **profile) as ds:
        ds.write(ground_z(xs[None, :], ys[:, None]).astype(np.float32), 1)
    return path


def metas(ground_source="class2", passed=3):
    tiles = [
        {
            "core_bounds": [X0, Y0, X0 + SIZE, Y0 + SIZE],
            "ground_source": ground_source,
            "counts": {"core": 200_000, "ground": 160_000, "noise": 12, "model_input": 40_000},
            "timings": {"ground": 1.5, "hag": 0.7},
        }
    ]
    preds = [
        {
            "windows_total": 25,
            "windows_passed_gate": passed,
            "windows_segmented": passed,
            "points_model_input_core": 40_000,
            "model": MODEL,
            "timings": {"classify": 0.4, "segment": 1.1},
            "peak_rss_mb": 812.0,
        }
    ]
    return tiles, preds


def report(out_dir, name, *, stem=None, **inputs):
    """block_report of block ``name`` to ``out_dir/<stem>.html`` and ``.json`` (stem: the name)
    with the schema's limits; the inputs default to BOUNDS and the tile/prediction metas of metas()."""
    tiles, preds = metas()
    stem = stem or name
    inputs = {"block_bounds": BOUNDS, "tile_metas": tiles, "pred_metas": preds, **inputs}
    return block_report(
        out_dir / f"{stem}.html", out_dir / f"{stem}.json", BlockInputs(block_name=name, **inputs), qa_limits()
    )


def test_block_report_page_and_json(tmp_path):
    pts = make_block()
    truth = pts["classification"].copy()
    # the model missed the legs of the second tower below 10 m: classified labels differ from truth
    cls = pts["classification"].copy()
    second = (truth == 15) & (pts["x"] > X0 + 100) & (pts["hag"] < 10)
    cls[second] = 1
    pts["classification"] = cls
    gdf = towers_of(pts)
    bench = tmp_path / "infer.tsv"
    bench.write_text(
        "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
        "12.5\t0:00:12\t1534.2\t2000\t1400\t1450\t10\t5\t90\t11.0\n"
    )
    doc = report(
        tmp_path,
        "b1",
        zone="z1",
        stats={"points_written": len(cls)},
        towers=gdf,
        classified=pts,
        truth=truth,
        timings={"infer_tile": str(bench), "merge_block": 3.25},
        warnings=["tile t3: 2 holes filled"],
    )
    page = (tmp_path / "b1.html").read_text()
    on_disk = json.loads((tmp_path / "b1.json").read_text())
    assert on_disk == json.loads(json.dumps(doc))
    # self-contained: images embedded, no external references
    assert page.count("data:image/png;base64,") >= 3
    assert not re.search(r"""(src|href)=["'](https?:|//|file:)""", page)
    assert "<link" not in page and "<script" not in page
    # numbers
    assert doc["n_towers"] == 2 and doc["points"] == len(cls)
    assert doc["windows_total"] == 25 and doc["windows_passed_gate"] == 3
    assert doc["ground_ratio"] == pytest.approx(np.mean(cls == 2))
    assert 3.0 < doc["density"]["density_median"] < 7.0
    acc = doc["accuracy"]
    assert acc["towers_true"] == 2 and acc["recall"] == 1.0 and acc["precision"] == 1.0
    expected_iou = np.sum((cls == 15) & (truth == 15)) / np.sum((cls == 15) | (truth == 15))
    assert acc["point_iou"] == pytest.approx(expected_iou) and acc["point_iou"] < 1.0
    infer = next(t for t in doc["timings"] if t["stage"] == "infer_tile")
    assert infer["seconds"] == 12.5 and infer["max_rss_mb"] == pytest.approx(1534.2)
    assert {"code": "warnings", "reason": "1 warning(s) during processing"} in doc["flags"]
    assert doc["status"] == "look"
    # the schema's limits (its qa section and five tower rules), keys in this order
    assert json.dumps(on_disk["limits"]) == (
        '{"min_density": 2.0, "min_ground_ratio": 0.05, "edge_margin_m": 2.0, "min_tower_prob": 0.6, '
        '"min_wire_support": 0.5, "wire_min_height": 15.0, "max_gate_ratio": 0.25, "min_recall": 1.0, '
        '"min_precision": 1.0, "min_point_recall": 0.5, "min_truth_points": 20, "mast_prominence": 2.0, "min_shape_score": 0.95}'
    )
    assert doc["summary"].startswith("2 towers found")
    for text in ("40006004600060", "tile t3: 2 holes filled", "Accuracy against", "peak memory (MB)"):
        assert text in page


def test_block_flags(tmp_path):
    pts = make_block(towers_at=((X0 + 2.0, Y0 + 100),), density=1.0)
    pts["prob"][pts["classification"] == 15] = 0.55
    gdf = towers_of(pts)
    assert len(gdf) == 1
    gdf["wire_support"] = 0.25  # a low tower kept without conductors (exempt from the rule)
    gdf["shape_score"] = 0.31  # kept by rule 12 or 13 though shaped like a tree
    tiles, preds = metas(ground_source="smrf", passed=20)
    doc = report(tmp_path, "b", tile_metas=tiles, pred_metas=preds, towers=gdf, classified=pts)
    codes = {f["code"] for f in doc["flags"]}
    assert {"ground_classified", "low_density", "many_windows_gated", "tower"} <= codes
    reasons = " ".join(f["reason"] for f in doc["flags"])
    assert "from the edge of the data" in reasons and "low mean probability" in reasons
    assert "few conductors found (support 0.25)" in reasons
    assert (
        "shaped like a tree (shape score 0.310, under 0.95), kept by rule 12 or 13 with conductor support 0.25"
        in reasons
    )
    assert doc["towers"][0]["flags"] and "1 needs a look" in doc["summary"]


def test_tower_whose_lines_may_leave_the_data_is_flagged(tmp_path):
    pts = make_block()
    gdf = towers_of(pts)
    gdf["wire_support"] = float("nan")  # towerpipe.towers.wires: a line through it may leave the data unseen
    doc = report(tmp_path, "b", towers=gdf, classified=pts)
    tall = [t for t in doc["towers"] if t["height_m"] >= 20]
    assert tall and all(any("conductor support not measured" in f for f in t["flags"]) for t in tall)
    # rule 13 keeps such a tall cluster under the shape threshold: not "by its conductors"
    gdf["shape_score"] = 0.9496
    doc = report(tmp_path, "b", stem="r13", towers=gdf, classified=pts)
    flags = [f for t in doc["towers"] if t["height_m"] >= 20 for f in t["flags"]]
    assert any(
        "(shape score 0.949, under 0.95), kept by rule 12 or 13 with its conductor support unknown" in f for f in flags
    )


def test_a_tower_passed_by_the_core_of_its_object_is_flagged(tmp_path):
    """Rule 9 judged it within 3 m of its top (its object, whole, looked like crowns): the page asks
    for a look; one passed whole, or without the shape check, is not flagged for its shape."""
    pts = make_block()
    gdf = towers_of(pts)
    gdf["wire_support"], gdf["shape_score"], gdf["shape_view"] = 1.0, 0.991, "core"
    doc = report(tmp_path, "b", towers=gdf, classified=pts)
    flags = [f for t in doc["towers"] for f in t["flags"]]
    assert len(flags) == len(gdf) and all(
        "shaped like a tower only near its top (shape score 0.991" in f for f in flags
    )
    assert [(t["shape_score"], t["shape_view"]) for t in doc["towers"]] == [(0.991, "core")] * len(gdf)
    assert "0.991<br>(core)" in (tmp_path / "b.html").read_text()
    for stem, view in (("whole", "object"), ("none", None)):
        gdf["shape_view"] = view
        doc = report(tmp_path, "b", stem=stem, towers=gdf, classified=pts)
        assert not any("near its top" in f for t in doc["towers"] for f in t["flags"])


def test_towers_of_a_delivery_without_a_wire_class_are_flagged(tmp_path):
    """A block whose tiles took their wires from the detector (no point classified 13/14) and that
    reports towers needs a look; a tile without wires in a delivery that classifies them does not."""
    pts = make_block()
    gdf = towers_of(pts)
    tiles, preds = metas()
    for sources, flagged in ((["detected"], True), (["classified", "detected"], False), (["classified"], False)):
        pm = [{**preds[0], "wire_source": s} for s in sources]
        doc = report(tmp_path, "b", stem=f"w{len(sources)}{flagged}", pred_metas=pm, towers=gdf, classified=pts)
        assert doc["wire_sources"] == sorted(sources)
        assert ("wires_detected" in {f["code"] for f in doc["flags"]}) == flagged
    page = (tmp_path / "w1True.html").read_text()
    assert "the wire detector (no wire class)" in page


def test_clean_block_is_ok_and_uses_raster(tmp_path):
    pts = make_block()
    tif = dtm_tif(tmp_path / "dtm.tif")  # used for the hillshade and HAG when points carry no HAG
    no_hag = {k: v for k, v in pts.items() if k != "hag"}
    gdf = towers_of(pts)
    doc = report(tmp_path, "b", zone="z1", towers=gdf, classified=no_hag, raster=tif)
    assert doc["status"] == "ok" and doc["flags"] == []
    assert doc["summary"] == "2 towers found; nothing to check."
    page = (tmp_path / "b.html").read_text()
    # the raster is the job's mosaic of the tiles' DTMs, not a product: named for what it is
    assert "z − the block&#39;s DTM" in page and "dtm.tif" not in page


def test_per_point_figures_do_not_depend_on_the_chunk_size(tmp_path, monkeypatch):
    """The density grid and the heights (from the DTM) are computed a chunk of points at a
    time, so a QA job holds no temporary of the block's size: any chunk size gives the same
    page, figures included."""
    import towerpipe.products.qa.block as qa_block
    import towerpipe.products.qa.metrics as qa_metrics

    pts = make_block()
    no_hag = {k: v for k, v in pts.items() if k != "hag"}
    tif, gdf = dtm_tif(tmp_path / "dtm.tif"), towers_of(pts)
    pages, point_chunks = [], qa_metrics.point_chunks
    for size in (qa_metrics.CHUNK_POINTS, 997):
        chunks = lambda n, size=size: point_chunks(n, size)  # noqa: E731
        monkeypatch.setattr(qa_block, "point_chunks", chunks)
        monkeypatch.setattr(qa_metrics, "point_chunks", chunks)
        out = tmp_path / f"c{size}"
        out.mkdir()
        doc = report(out, "b", zone="z1", towers=gdf, classified=no_hag, raster=tif)
        pages.append((doc, re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", (out / "b.html").read_text())))
    (a, figs_a), (b, figs_b) = pages
    assert a["density"] == b["density"] and figs_a == figs_b and len(figs_a) >= 3
    assert len(no_hag["x"]) > 997 * 10  # many chunks


def test_clipped_histogram_counts_the_clipped_values_in_the_end_bins():
    from towerpipe.products.qa.plots import clipped_histogram

    a = np.random.default_rng(3).normal(5.0, 10.0, 10_000)
    a[:3] = [-50.0, 12.0, 99.0]  # below, at and above the range
    rng = (-2.0, 12.0)
    counts, edges = clipped_histogram(a, rng)
    want, want_edges = np.histogram(np.clip(a, *rng), bins=79, range=rng)
    np.testing.assert_array_equal(counts, want)
    np.testing.assert_array_equal(edges, want_edges)


def test_histogram_counts_are_labelled_as_short_plain_text():
    from towerpipe.products.qa.plots import count_label

    got = [count_label(v) for v in (1, 10, 100, 1e3, 1e4, 1e5, 1e6, 2.5e6)]
    assert got == ["1", "10", "100", "1k", "10k", "100k", "1M", "2.5M"]  # no 10^n: no mathematical text


def test_the_delivery_own_classes_are_listed_with_their_heights(tmp_path):
    # LiDAR HD's artefacts (class 65) as a curtain up to 80 m above the ground beside a tower: points
    # of the scene for the model, listed on the page (the noise classes were taken out by the split)
    pts = make_block()
    h = np.linspace(0.0, 80.0, 60)
    curtain = {"x": np.full(60, X0 + 64.0), "y": np.full(60, Y0 + 60.0), "hag": h.astype(np.float32)}
    curtain["z"] = ground_z(curtain["x"], curtain["y"]) + h
    extra = {**curtain, "classification": np.full(60, 65, np.uint8), "prob": np.zeros(60, np.float32)}
    pts = {k: np.concatenate([pts[k], extra[k]]) for k in pts}
    doc = report(tmp_path, "b", zone="z1", towers=towers_of(pts), classified=pts)
    assert doc["user_classes"] == {"65": {"points": 60, "hag_max": 80.0}}  # as in the JSON
    row = "input: class 65, the delivery's own, taken as any point (up to 80.0 m above the ground)"
    assert doc["stage_counts"][row] == 60
    assert "class 65, the delivery&#39;s own" in (tmp_path / "b.html").read_text()
    assert (
        report(tmp_path, "c", zone="z1", towers=towers_of(make_block()), classified=make_block())["user_classes"] == {}
    )
    # the zone's index sums them over its blocks, in a section of its own only when there are some
    index = zone_index(tmp_path / "index.html", [tmp_path / "b.json", tmp_path / "c.json"], zone="z1")
    assert index["user_classes"] == [{"class": 65, "blocks": 1, "points": 60, "hag_max": 80.0}]
    assert "Classes of the delivery's own" in (tmp_path / "index.html").read_text()
    zone_index(tmp_path / "index_c.html", [tmp_path / "c.json"], zone="z1")
    assert "Classes of the delivery" not in (tmp_path / "index_c.html").read_text()


def test_block_report_from_files_and_no_towers(tmp_path):
    import laspy

    pts = make_block(towers_at=())
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = [X0, Y0, 0]
    header.scales = [0.01, 0.01, 0.01]
    header.add_extra_dim(laspy.ExtraBytesParams(name="TowerProbability", type=np.float32))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts["x"], pts["y"], pts["z"]
    las.classification = pts["classification"]
    las["TowerProbability"] = pts["prob"]
    las.write(tmp_path / "b.laz")
    loaded = load_classified(tmp_path / "b.laz")
    assert set(loaded) == {"x", "y", "z", "classification", "prob"}
    from towerpipe.products.gpkg import write_towers_gpkg

    gpkg = write_towers_gpkg(tmp_path / "b.gpkg", None, crs_wkt="EPSG:25831")
    doc = report(
        tmp_path, "b", block_bounds=None, tile_metas=(), pred_metas=(), towers=gpkg, classified=tmp_path / "b.laz"
    )
    assert doc["n_towers"] == 0 and doc["summary"].startswith("0 towers found")
    assert "No towers in this block" in (tmp_path / "b.html").read_text()


def test_read_benchmark_repeats_and_na(tmp_path):
    p = tmp_path / "b.tsv"
    p.write_text("s\th:m:s\tmax_rss\tcpu_time\n10\t0:00:10\t100\tNA\n20\t0:00:20\t300\tNA\n")
    assert read_benchmark(p) == {"seconds": 15.0, "max_rss_mb": 300.0}
    # a job Snakemake's sampler never saw working (cpu_time 0): its memory is not known
    p.write_text("s\th:m:s\tmax_rss\tcpu_time\n0.48\t0:00:00\t7.2\t0.00\n")
    assert read_benchmark(p) == {"seconds": 0.48, "cpu_seconds": 0.0}
    p.write_text("s\th:m:s\tmax_rss\tcpu_time\n0.5\t0:00:00\t7.2\t0.00\n2.5\t0:00:02\t412\t2.1\n")
    assert read_benchmark(p)["max_rss_mb"] == 412.0


def _benchmark(path, seconds: float, rss: float):
    """A Snakemake benchmark TSV of one run."""
    path.write_text(f"s\th:m:s\tmax_rss\n{seconds}\t0:00:03\t{rss}\n")
    return path


def test_zone_index(tmp_path):
    ok = report(tmp_path / "qa", "a", zone="z1", towers=towers_of(make_block()), classified=make_block())
    tiles2, preds2 = metas(ground_source="smrf")
    look = report(
        tmp_path / "qa", "b", zone="z1", tile_metas=tiles2, pred_metas=preds2, classified=make_block(towers_at=())
    )
    assert (ok["status"], look["status"]) == ("ok", "look")
    doc = zone_index(
        tmp_path / "index.html",
        [tmp_path / "qa" / "a.json", tmp_path / "qa" / "b.json"],
        failures={"c": "merge_block failed: see logs/z1/merge_block/c.log"},
        zone="z1",
        out_json=tmp_path / "index.json",
        # the merge runs beside the block's QA page: the index reports it (b's was not recorded)
        merge_benchmarks={"a": _benchmark(tmp_path / "merge_a.tsv", 3.25, 512.0), "b": tmp_path / "none.tsv"},
        # each block's input file, also the failed one's (b: none given, none in its QA JSON)
        sources={"a": "flight 1/a.laz", "c": "flight 1/c.laz"},
    )
    assert [b["block"] for b in doc["blocks"]] == ["c", "b", "a"]
    assert [b["input"] for b in doc["blocks"]] == ["flight 1/c.laz", None, "flight 1/a.laz"]
    merge = {b["block"]: (b.get("merge_s"), b.get("merge_rss_mb")) for b in doc["blocks"]}
    assert merge == {"a": (3.25, 512.0), "b": (None, None), "c": (None, None)}
    t = doc["totals"]
    assert (t["blocks"], t["failed"], t["look"], t["ok"], t["towers"]) == (4 - 1, 1, 1, 1, 2)
    assert t["summary"] == "2 towers found in 3 blocks; 1 failed; 1 needs a look."
    page = (tmp_path / "index.html").read_text()
    assert 'href="qa/a.html"' in page and "merge_block failed" in page and "ground classified" in page
    assert page.count('<span class="muted">flight 1/') == 2
    assert page.count("LAZ merged in") == 1 and "LAZ merged in 3.2 s, peak memory 512 MB" in page
    assert json.loads((tmp_path / "index.json").read_text())["totals"]["towers"] == 2
    # no zone GeoPackage (every block failed, or none given): no link to it, and the page says so
    assert "towers.gpkg</a>" not in page and 'href="../towers.gpkg"' not in page
    assert "no <code>towers.gpkg</code> was written" in page


def test_edge_tower_reported_by_the_neighbour_counts_as_found(tmp_path):
    # half of a labelled tower lies in this block, the neighbour (east) owns and reports it
    pts = make_block(towers_at=((X0 + 60, Y0 + 60), (X0 + SIZE - 0.5, Y0 + 100)))
    inside = pts["x"] < X0 + SIZE
    pts = {k: v[inside] for k, v in pts.items()}
    # with the neighbour's predictions the whole tower's centroid is east of the edge: this
    # block reports only its first tower
    gdf = towers_of(pts)
    gdf = gdf[gdf["centroid_x"] < X0 + 100]
    assert len(gdf) == 1
    truth = pts["classification"].copy()
    kw = dict(zone="z1", towers=gdf, classified=pts, truth=truth)
    alone = report(tmp_path, "b1", stem="a", **kw)
    assert alone["accuracy"]["recall"] == 0.5 and alone["status"] == "look"
    full_tower = tower(X0 + SIZE - 0.5, Y0 + 100)
    import shapely

    nb = [
        {
            "tower_id": "T_z1_east",
            "footprint_wkt": shapely.MultiPoint(full_tower[:, :2]).convex_hull.wkt,
            "blocks": "b1,b2",
        }
    ]
    # the points of the block in each tower (the towers job's tower-points file): the seam
    # tower's are counted apart, under the id the neighbour reports it with
    here = {int(gdf["tower_id"].iloc[0]): 300, 40020004600100: 57}
    doc = report(tmp_path, "b1", stem="b", neighbour_towers=nb, tower_points_here=here, **kw)
    acc = doc["accuracy"]
    assert acc["recall"] == 1.0 and acc["precision"] == 1.0 and acc["fn"] == 0
    assert any(m.get("owner") == "neighbour" for m in acc["matches"])
    assert not any(f["code"] == "missed_towers" for f in doc["flags"])
    assert doc["stage_counts"]["… of them in towers a neighbouring block reports (40020004600100)"] == 57


def test_labelled_tower_points_in_no_reported_tower_flag_the_block(tmp_path):
    """The west part of a labelled tower whose centroid lies in the neighbour block, missed by
    both: no tower of the block's own to miss, so the tower recall says nothing; the page said
    "nothing to check". The share of its labelled points in a reported tower flags it."""
    pts = make_block(towers_at=((X0 + SIZE + 1.5, Y0 + 100),))
    labelled = pts["classification"] == classes.TOWER
    whole = {k: pts[k][labelled] for k in ("x", "y", "z", "hag")}  # the block's tiles see it whole
    inside = pts["x"] < X0 + SIZE
    pts = {k: v[inside] for k, v in pts.items()}
    truth = pts["classification"].copy()
    missed = {**pts, "prob": np.zeros_like(pts["prob"]), "classification": np.where(truth == 15, 1, truth)}
    kw = dict(zone="z1", truth=truth, truth_points=whole)
    doc = report(tmp_path, "b1", towers=towers_of(missed), classified=missed, **kw)
    assert doc["accuracy"]["towers_true"] == 0 and doc["accuracy"]["points_true"] >= 20
    (flag,) = [f for f in doc["flags"] if f["code"] == "missed_tower_points"]
    assert flag["reason"].endswith("labelled 15 here are in no reported tower (0% found)") and doc["status"] == "look"
    found = report(tmp_path, "b1", stem="f", towers=towers_of(pts), classified=pts, **kw)
    assert not any(f["code"] == "missed_tower_points" for f in found["flags"])


def test_a_labelled_tower_on_the_seam_counts_in_the_block_of_its_centroid(tmp_path):
    """From the block's own points, the west half of a labelled tower standing 1.5 m east of
    the block's edge is a labelled tower of the block (its centroid is inside); from the
    labelled points of the block's tiles, core and buffer (``truth_points``), the tower is
    whole and counts in the block east of the edge only: each seam tower counts once."""
    pts = make_block(towers_at=((X0 + 60, Y0 + 60), (X0 + SIZE + 1.5, Y0 + 100)))
    labelled = pts["classification"] == classes.TOWER
    whole = {k: pts[k][labelled] for k in ("x", "y", "z", "hag")}
    inside = pts["x"] < X0 + SIZE
    pts = {k: v[inside] for k, v in pts.items()}
    gdf = towers_of(pts)
    gdf = gdf[gdf["centroid_x"] < X0 + 100]
    kw = dict(zone="z1", towers=gdf, classified=pts, truth=pts["classification"].copy())
    halves = report(tmp_path, "b1", stem="a", **kw)["accuracy"]
    assert halves["towers_true"] == 2 and halves["recall"] == 0.5
    acc = report(tmp_path, "b1", stem="b", truth_points=whole, **kw)["accuracy"]
    assert acc["towers_true"] == 1 and acc["recall"] == 1.0 and acc["precision"] == 1.0
    assert acc["point_iou"] == halves["point_iou"]  # over the block's own points either way


def seam_labels():
    """A tower on b1's east edge: the centroid of its reported footprint 0.3 m west of the edge
    (b1 reports it), that of its labelled points, core and buffer, 0.3 m east (b1's points, its
    labelled towers whole, the tower)."""
    pts = make_block(towers_at=((X0 + SIZE - 0.3, Y0 + 100),))
    gdf = towers_of(pts)
    assert len(gdf) == 1 and gdf["centroid_x"].iloc[0] < X0 + SIZE < gdf.geometry.iloc[0].bounds[2]
    labelled = pts["classification"] == classes.TOWER
    whole = {k: pts[k][labelled] + (0.6 if k == "x" else 0.0) for k in ("x", "y", "z", "hag")}
    assert whole["x"].mean() > X0 + SIZE
    inside = pts["x"] < X0 + SIZE
    return {k: v[inside] for k, v in pts.items()}, whole, gdf


def test_a_tower_reported_here_and_labelled_across_the_seam_is_not_false(tmp_path):
    # found here (precision), counted in the neighbour's recall, which lists it as a tower of b1's
    # with points in the neighbour
    pts, whole, gdf = seam_labels()
    doc = report(tmp_path, "b1", towers=gdf, classified=pts, truth=pts["classification"].copy(), truth_points=whole)
    acc = doc["accuracy"]
    assert acc["towers_true"] == 0 and (acc["tp"], acc["fp"], acc["precision"]) == (1, 0, 1.0)
    assert [x["owner"] for x in acc["matches"]] == ["labelled across the seam"]
    assert "false_towers" not in {f["code"] for f in doc["flags"]}
    # the neighbour's side: the labelled tower is its own, and b1's tower finds it
    east = (X0 + SIZE, Y0, X0 + 2 * SIZE, Y0 + SIZE)
    nb = [{"tower_id": str(gdf["tower_id"].iloc[0]), "footprint_wkt": gdf.geometry.iloc[0].wkt, "blocks": "b1,b2"}]
    m = label_accuracy(
        pts, pts["classification"], gdf.iloc[:0], east, min_truth_points=20, neighbour_towers=nb, truth_points=whole
    )
    assert (m["towers_true"], m["tp"], m["fn"], m["recall"]) == (1, 0, 0, 1.0)


def test_a_tower_across_the_seam_is_found_once(tmp_path):
    pts, whole, gdf = seam_labels()
    kw = dict(classified=pts, truth=pts["classification"].copy(), truth_points=whole)
    # the labelled tower split in two: the part the neighbour reports lies on it, b1's part 0.6 m
    # away; the labelled tower is the neighbour's part's, and b1's stays false
    part = shapely.affinity.translate(gdf.geometry.iloc[0], xoff=0.6)
    nb = [{"tower_id": "b2part", "footprint_wkt": part.wkt, "blocks": "b1,b2"}]
    acc = report(tmp_path, "b1", stem="split", towers=gdf, neighbour_towers=nb, **kw)["accuracy"]
    assert (acc["tp"], acc["fp"], acc["precision"]) == (0, 1, 0.0)
    # a tower wholly in b1 near a labelled tower across the seam: the neighbour does not list it, so
    # b1 does not count it as found either
    small = gdf.copy()
    small["geometry"] = [shapely.box(X0 + SIZE - 2.5, Y0 + 99.5, X0 + SIZE - 1.5, Y0 + 100.5)]
    acc = report(tmp_path, "b1", stem="inside", towers=small, **kw)["accuracy"]
    assert (acc["tp"], acc["fp"]) == (0, 1)


# --------------------------------------------------------------------------- the edge of the data
def seam_setup():
    """A tower straddling the east edge of block b1 (BOUNDS) and its east neighbour b2."""
    east = (X0 + SIZE, Y0, X0 + 2 * SIZE, Y0 + SIZE)
    pts = make_block(towers_at=((X0 + SIZE - 0.5, Y0 + 100),))
    gdf = towers_of(pts)  # built from all its points, as the towers step does with the neighbour's
    assert len(gdf) == 1 and gdf.geometry.iloc[0].bounds[2] > X0 + SIZE
    return pts, gdf, east


def test_seam_tower_handled_whole_is_not_flagged(tmp_path):
    pts, gdf, east = seam_setup()
    # the neighbour gave points: the tower is whole, its centroid 0.5 m from the seam does not matter
    doc = report(tmp_path, "b1", stem="b", towers=gdf, classified=pts, data_bounds=[BOUNDS, east])
    t = doc["towers"][0]
    assert t["edge_distance_m"] == pytest.approx(0.5, abs=0.2)
    assert t["flags"] == [] and doc["status"] == "ok"
    assert t["data_edge_m"] > 90


def test_tower_at_the_zone_edge_or_a_failed_neighbour_is_flagged(tmp_path):
    pts, gdf, _ = seam_setup()
    # no block east of b1 (zone edge), or its neighbour could not be read: the tower may be cut
    doc = report(tmp_path, "b1", stem="b", towers=gdf, classified=pts, data_bounds=[BOUNDS])
    t = doc["towers"][0]
    assert t["data_edge_m"] == 0.0
    assert len(t["flags"]) == 1 and "may be cut" in t["flags"][0]


def test_data_edge_joins_adjoining_blocks_without_a_slit():
    import shapely

    from towerpipe.products.qa.metrics import data_extent, distance_to_data_edge

    # header bounds end at the last point, 1 cm before the next block starts
    extent = data_extent([(0, 0, 99.99, 100), (100, 0, 200, 100)])
    on_seam = shapely.box(97, 40, 103, 46)
    assert distance_to_data_edge(on_seam, extent) == pytest.approx(40 + 1.0)  # to the grown south edge
    assert distance_to_data_edge(shapely.box(195, 40, 203, 46), extent) == 0.0


# --------------------------------------------------------------------------- side views
def test_side_views_see_a_seam_tower_whole(tmp_path):
    from towerpipe.io.members import save_members
    from towerpipe.io.tiles import Tile, empty_arrays, save_tile
    from towerpipe.products.qa.neighbourhoods import tower_neighbourhoods

    pts, gdf, _ = seam_setup()
    tid = gdf["tower_id"].iloc[0]
    # noise 700 m above the tower, classified (18) or only out of the tile's height range (class 1,
    # 700 m above ground): never in its side views (it would set their scale)
    cx, cy = gdf["centroid_x"].iloc[0], gdf["centroid_y"].iloc[0]
    top = float(pts["z"].max()) + 700.0
    for cls, hag in ((classes.HIGH_NOISE, 50.0), (1, 700.0)):
        noise = {"x": cx - 2.0, "y": cy, "z": top, "classification": cls, "prob": 0.0, "hag": hag}
        pts = {k: np.append(v, noise.get(k, v[-1])).astype(v.dtype) for k, v in pts.items()}
    # two blocks split at the seam: b1's tile holds its core and b2's points as buffer
    in_b1 = pts["x"] < X0 + SIZE
    idx = {b: np.flatnonzero(m) for b, m in (("b1", in_b1), ("b2", ~in_b1))}
    arrays = empty_arrays(len(pts["x"]))
    for k in ("x", "y", "z", "hag", "classification"):
        arrays[k] = pts[k].astype(arrays[k].dtype)
    arrays["block_id"] = np.where(in_b1, 0, 1).astype(np.int32)
    arrays["point_index"] = np.zeros(len(in_b1), np.int64)
    for i in idx.values():
        arrays["point_index"][i] = np.arange(len(i))
    arrays["core"] = in_b1
    tile = tmp_path / "t.npz"
    save_tile(
        tile, Tile(arrays, {"blocks": ["b1", "b2"], "core_bounds": list(BOUNDS), "hag_min": -5.0, "hag_max": 100.0})
    )
    is_tower = pts["classification"] == 15
    members = tmp_path / "b1.points.npz"
    save_members(members, {tid: (np.where(in_b1[is_tower], "b1", "b2"), arrays["point_index"][is_tower])})
    # the same tile given twice (a buffer point is in several tiles): each point once
    hoods = tower_neighbourhoods([tile, tile], [members], gdf)
    hood = hoods[tid]
    assert hood["tower"].sum() == is_tower.sum()
    assert hood["x"][hood["tower"]].max() > X0 + SIZE  # the neighbour's half of the tower is there
    assert len(hood["x"]) == len(np.unique(np.column_stack([hood["x"], hood["y"], hood["z"]]), axis=0))
    assert hood["z"].max() < top - 600  # both noise points are left out
    report(tmp_path, "b1", stem="b", towers=gdf, classified=pts, neighbourhoods=hoods)
    page = (tmp_path / "b.html").read_text()
    assert 'id="tower-1"' in page and 'href="#tower-1"' in page and "Side views" in page


# --------------------------------------------------------------------------- contracts with the split and the model
ATTRIBUTES = {
    "intensity": {"valid": True, "reason": "2,471 distinct values"},
    "returns": {"valid": False, "reason": "return numbers all 0"},
    "rgb": {"valid": True, "reason": "16-bit colour"},
    "nir": {"valid": True, "reason": "varies"},
}


def test_sensor_attributes_and_model_choice(tmp_path):
    _, preds = metas()
    preds[0]["model"] = dict(MODEL, choice={"mode": "auto", "reason": "the zone's return numbers are all 0"})
    summary = {"attributes": ATTRIBUTES, "degenerate_attributes": ["returns"], "crs_wkt": 'PROJCRS["x" ' * 80}
    doc = report(tmp_path, "b1", stem="b", pred_metas=preds, classified=make_block(towers_at=()), stats=summary)
    assert {
        "code": "degenerate_attributes",
        "reason": "sensor attributes unusable: returns (return numbers all 0)",
    } in doc["flags"]
    assert doc["model"]["choice"]["mode"] == "auto"
    page = (tmp_path / "b.html").read_text()
    assert "Sensor attributes" in page and "2,471 distinct values" in page
    assert "Model used and why</b> (auto): the zone&#39;s return numbers are all 0" in page
    # raw metadata (WKT, JSON) is folded away, not in a table
    details = page[page.index("<details>") : page.index("</details>")]
    assert "PROJCRS" in details and "PROJCRS" not in page.replace(details, "")


def test_page_of_an_older_run_without_attributes_or_choice(tmp_path):
    doc = report(tmp_path, "b1", stem="b", classified=make_block(towers_at=()))
    page = (tmp_path / "b.html").read_text()
    assert doc["attributes"] == {} and "Sensor attributes" not in page and "Model used and why" not in page


def test_block_page_links_to_index_and_products(tmp_path):
    report(tmp_path / "qa", "b1", classified=make_block(towers_at=()))
    page = (tmp_path / "qa" / "b1.html").read_text()
    for href in ("index.html", "../blocks/b1.laz", "../towers/b1.gpkg", "../towers.gpkg"):
        assert f'href="{href}"' in page


# --------------------------------------------------------------------------- zone index
def test_zone_index_counts_a_tower_of_two_overlapping_blocks_once(tmp_path):
    """Two blocks that overlap both list the tower in the overlap; the zone's GeoPackage holds
    it once, and so do the index's totals and summary (they summed the blocks' counts)."""
    pts = make_block()
    for b in ("a", "a_overlap"):
        report(tmp_path / "qa", b, zone="z1", towers=towers_of(pts), classified=pts)
    jsons = [tmp_path / "qa" / "a.json", tmp_path / "qa" / "a_overlap.json"]
    assert zone_index(tmp_path / "i0.html", jsons, zone="z1")["totals"]["towers"] == 4  # the blocks' sum
    doc = zone_index(tmp_path / "index.html", jsons, zone="z1", n_towers=2)
    assert doc["totals"]["towers"] == 2 and doc["totals"]["summary"].startswith("2 towers found in 2 blocks")
    assert [b["n_towers"] for b in doc["blocks"]] == [2, 2]  # each block still lists its own
    # a file of zero points: listed among the blocks that need a look, not failed
    doc = zone_index(tmp_path / "index.html", jsons, zone="z1", n_towers=2, empty={"sea": "flight/sea.laz"})
    assert doc["blocks"][0]["block"] == "sea" and doc["blocks"][0]["codes"] == ["empty"]
    assert doc["totals"]["failed"] == 0 and doc["totals"]["summary"].endswith("1 needs a look.")
    assert "flight/sea.laz: the file holds zero points" in (tmp_path / "index.html").read_text()


def test_zone_index_map_with_lines_and_failed_block(tmp_path):
    import geopandas as gpd
    import shapely

    from towerpipe.products.gpkg import write_towers_gpkg

    qa = tmp_path / "qa"
    pts = make_block()
    report(qa, "a", zone="z1", towers=towers_of(pts), classified=pts)
    gpkg = write_towers_gpkg(tmp_path / "towers.gpkg", towers_of(pts), crs_wkt="EPSG:25831")
    line = shapely.LineString([(X0 + 60, Y0 + 60), (X0 + 150, Y0 + 120)])
    gpd.GeoDataFrame({"line_id": ["L1"]}, geometry=[line], crs="EPSG:25831").to_file(gpkg, layer="lines")
    failed_box = (X0 + SIZE, Y0, X0 + 2 * SIZE, Y0 + SIZE)
    doc = zone_index(
        tmp_path / "qa" / "index.html",
        [qa / "a.json"],
        failures={"c": "split_block: InputError: c.laz"},
        zone="z1",
        gpkg=gpkg,
        block_bounds={"c": failed_box},
    )
    assert doc["n_lines"] == 1
    assert [b["bounds"] for b in doc["blocks"]] == [list(failed_box), list(BOUNDS)]
    page = (qa / "index.html").read_text()
    svg = page[page.index("<svg") : page.index("</svg>")]
    assert 'xlink:href="a.html"' in svg or 'href="a.html"' in svg  # the map's block links to its page
    assert "<!-- block: failed -->" in svg and "<!-- line -->" in svg  # matplotlib keeps each text as a comment
    assert "http" not in svg and "_blank" not in svg  # no namespace or metadata addresses; links open in place
    for href in ('href="../blocks/a.laz"', 'href="../towers/a.gpkg"', 'href="../towers.gpkg"', 'href="a.html"'):
        assert href in page
    assert "incomplete" in page


def test_fill_nearest_fills_holes_and_leaves_a_full_grid_alone():
    from towerpipe.products.qa.plots import fill_nearest

    full = np.arange(12.0).reshape(3, 4)
    np.testing.assert_array_equal(fill_nearest(full), full)
    holed = full.copy()
    holed[0, 0] = holed[2, 3] = np.nan
    filled = fill_nearest(holed)
    assert np.isfinite(filled).all()
    assert filled[0, 0] in (1.0, 4.0) and filled[2, 3] in (7.0, 10.0)  # a nearest neighbour's value
    np.testing.assert_array_equal(fill_nearest(np.full((2, 2), np.nan)), np.zeros((2, 2)))


def test_tower_numbers_on_the_block_map_stay_inside_its_axes(monkeypatch):
    # a tower near the block's top or right edge had its number drawn over the figure's title
    import geopandas as gpd
    import shapely

    from towerpipe.products.qa import plots

    figs = []
    monkeypatch.setattr(plots, "png", lambda fig, dpi=100: figs.append(fig) or "")
    bounds = (400_000.0, 4_600_000.0, 400_250.0, 4_600_250.0)
    at = [(400_010.0, 4_600_248.0), (400_248.0, 4_600_248.0), (400_248.0, 4_600_005.0), (400_125.0, 4_600_125.0)]
    towers = gpd.GeoDataFrame(
        {"centroid_x": [x for x, _ in at], "centroid_y": [y for _, y in at]},
        geometry=[shapely.box(x - 2, y - 2, x + 2, y + 2) for x, y in at],
    )
    plots.block_map(towers, bounds, None, None, 1.0, "the block's DTM")
    fig = figs[0]
    fig.canvas.draw()
    ax = fig.axes[0]
    inside = ax.get_window_extent()
    labels = [t for t in ax.texts if t.get_text() in {"1", "2", "3", "4"}]
    assert len(labels) == 4
    for t in labels:
        box = t.get_window_extent()
        assert inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1, t.get_text()


def test_a_tower_an_analyst_reviewed_no_longer_makes_its_block_need_a_look(tmp_path):
    """The zone's GeoPackage holds the analysts' reviews: a flag of a confirmed or rejected tower
    is shown as reviewed on the index, and its block needs a look only for its other flags."""
    from towerpipe.products.gpkg import write_towers_gpkg

    qa = tmp_path / "qa"
    pts = make_block()
    towers = towers_of(pts)
    towers["prob_mean"] = 0.4  # both towers flagged: a low mean probability
    d = report(qa, "a", zone="z1", towers=towers, classified=pts)
    assert d["status"] == "look" and [f["code"] for f in d["flags"]] == ["tower", "tower"]
    first, second = (str(t) for t in towers["tower_id"])
    gpkg = tmp_path / "towers.gpkg"

    def index_with(statuses):
        write_towers_gpkg(gpkg, towers.assign(review_status=statuses), crs_wkt="EPSG:25831")
        return zone_index(tmp_path / "qa" / "index.html", [qa / "a.json"], zone="z1", gpkg=gpkg)["blocks"][0]

    b = index_with(["unreviewed", "unreviewed"])
    assert b["status"] == "look" and b["codes"] == ["tower", "tower"]
    b = index_with(["confirmed", "unreviewed"])
    assert b["status"] == "look" and b["codes"] == ["tower", "reviewed"]
    assert b["reasons"][1].startswith(f"tower 1 ({first}): ") and b["reasons"][1].endswith(" (reviewed: confirmed)")
    b = index_with(["confirmed", "rejected"])
    assert b["status"] == "ok" and b["codes"] == ["reviewed", "reviewed"]
    assert f"tower 2 ({second}): " in b["reasons"][1] and "(reviewed: rejected)" in b["reasons"][1]
    page = (qa / "index.html").read_text()
    assert "nothing to check" in page and "(reviewed: rejected)" in page
    # a flag that is not a tower's stays: the block still needs a look for it
    d = report(qa, "a", zone="z1", towers=towers, classified=pts, warnings=["a warning"])
    b = index_with(["confirmed", "rejected"])
    assert b["status"] == "look" and b["codes"] == ["warnings", "reviewed", "reviewed"]
