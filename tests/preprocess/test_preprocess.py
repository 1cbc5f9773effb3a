"""Preprocessing on real IGN tiles: ground, DTM, HAG, noise, tiles and neighbour buffers."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
import rasterio

from conftest import HIGH_NOISE, RGB_SUBSET, RGBNIR_BLOCK, RGBNIR_SMALL, preprocess_settings
from towerpipe.io.blockcache import BlockCache
from towerpipe.io.tiles import load_tile
from towerpipe.preprocess import tiling
from towerpipe.preprocess.split import split_block
from towerpipe.preprocess.tile import gather_tile, preprocess_tile, summarize_block, tile_noise

pytestmark = pytest.mark.usefixtures("pdal_cli")


def run_block(tmp_path, path, *, block="b", tile_size=500.0, extra=None):
    """split + every tile of one block; returns (split meta, {tile: Tile})."""
    cfg = preprocess_settings(tile_size=tile_size, **(extra or {}))
    cache = tmp_path / "cache" / block
    meta = split_block(path, cache, block=block, zone="z", settings=cfg)
    tiles = {}
    for t in tiling.tile_ids(tuple(meta["header_bounds"]), tile_size):
        out = tmp_path / "tiles" / f"{t}.npz"
        preprocess_tile("z", block, t, {block: cache}, out, dtm_path=tmp_path / "dtm" / f"{t}.tif", settings=cfg)
        tiles[t] = load_tile(out)
    return meta, tiles


@pytest.fixture(scope="module")
def rgbnir(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rgbnir")
    return tmp, *run_block(tmp, RGBNIR_BLOCK, tile_size=150.0)


def core_points(tiles):
    return {
        k: np.concatenate([t[k][t["core"]] for t in tiles.values()])
        for k in ("point_index", "hag", "classification", "model_input", "z")
    }


@pytest.mark.shared
def test_every_point_in_exactly_one_tile_core(rgbnir):
    _, meta, tiles = rgbnir
    assert len(tiles) > 1, "the test needs several tiles"
    idx = np.sort(core_points(tiles)["point_index"])
    np.testing.assert_array_equal(idx, np.arange(meta["points"]))


@pytest.mark.shared
def test_ground_hag_near_zero_and_roofs_plausible(rgbnir):
    _, _, tiles = rgbnir
    c = core_points(tiles)
    ground = c["classification"] == 2
    assert np.median(np.abs(c["hag"][ground])) < 0.05
    # vegetation classes ordered by height band
    med = [np.median(c["hag"][c["classification"] == k]) for k in (3, 4, 5)]
    assert med[0] < med[1] < med[2]


@pytest.mark.shared
def test_building_roofs_get_plausible_hag(tmp_path):
    _, tiles = run_block(tmp_path, RGB_SUBSET, tile_size=50.0)
    c = core_points(tiles)
    roofs = c["hag"][c["classification"] == 6]
    assert roofs.size > 5000
    # IGN town houses: roofs a few metres up, none underground or skyscraper-high
    assert 3.0 < np.median(roofs) < 15.0
    assert np.percentile(roofs, 5) > 1.0 and np.percentile(roofs, 99) < 30.0
    ground = c["hag"][c["classification"] == 2]
    assert np.median(np.abs(ground)) < 0.05


@pytest.mark.shared
def test_model_input_excludes_ground_and_keeps_vegetation(rgbnir):
    _, _, tiles = rgbnir
    c = core_points(tiles)
    assert not c["model_input"][c["classification"] == 2].any()
    assert c["model_input"][c["classification"] == 5].mean() > 0.99


@pytest.mark.shared
def test_dtm_holes_filled(rgbnir):
    tmp, _, tiles = rgbnir
    had_holes = False
    for t, tile in tiles.items():
        if len(tile) == 0:
            continue
        assert np.isfinite(tile["hag"]).all()
        with rasterio.open(tmp / "dtm" / f"{t}.tif") as ds:
            dtm = ds.read(1, masked=True)
            assert not np.ma.is_masked(dtm) or dtm.mask.sum() == 0, f"tile {t}: DTM has nodata cells left"
            assert ds.crs is not None
        had_holes |= tile.meta["dtm"]["empty_cells"] > 0
    assert had_holes, "the IGN tile has buildings, so its raw DTM must have had holes to fill"


@pytest.mark.shared
def test_high_noise_points_out_of_model_input(tmp_path):
    meta, tiles = run_block(tmp_path, HIGH_NOISE)
    c = core_points(tiles)
    high = c["hag"] > 100.0
    # the file holds ~27 noise points up to ~1,360 m above the terrain
    assert 20 <= high.sum() <= 40
    assert c["hag"].max() > 1000.0
    assert not c["model_input"][high].any()
    assert c["hag"][c["model_input"]].max() <= 100.0
    summary = summarize_block(tmp_path / "cache" / "b", [str(tmp_path / "tiles" / f"{t}.npz") for t in tiles])
    assert summary["counts"]["noise_hag_core"] >= 20
    assert summary["points"] == meta["points"]
    # read back from the written tiles (the QA's side views leave these points out)
    for t in tiles:
        tile = load_tile(tmp_path / "tiles" / f"{t}.npz")
        noise = tile_noise(tile)
        assert noise[tile.arrays["hag"] > 100.0].all()
        assert not (noise & tile.arrays["model_input"]).any()
        assert noise.sum() < 0.01 * len(noise)


def split_file(src, out_dir, x_cut):
    """Cut a real file in two blocks at x = x_cut (every attribute and VLR kept)."""
    las = laspy.read(src)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, mask in (("west", las.x < x_cut), ("east", las.x >= x_cut)):
        part = laspy.LasData(las.header)
        part.points = las.points[mask]
        part.write(out_dir / f"{name}.laz")
        paths.append(out_dir / f"{name}.laz")
    return paths


def two_blocks(tmp_path):
    """The real RGB+NIR block cut in two at its middle, both split: (west's LAS, the cut,
    west's bounds, the settings of three tile columns with a 40 m buffer, the caches, the west
    tile touching the cut)."""
    src = RGBNIR_BLOCK
    hdr = laspy.open(src).header
    x_cut = float(np.floor((hdr.mins[0] + hdr.maxs[0]) / 2))
    west, east = split_file(src, tmp_path / "in", x_cut)
    w = laspy.read(west)
    wb = (float(w.header.mins[0]), float(w.header.mins[1]), float(w.header.maxs[0]), float(w.header.maxs[1]))
    size = (wb[2] - wb[0]) / 3 + 1e-6  # three tile columns; the third ends at the cut
    cfg = preprocess_settings(tile_size=size, buffer=40.0)
    caches = {}
    for p in (west, east):
        caches[p.stem] = tmp_path / "cache" / p.stem
        split_block(p, caches[p.stem], block=p.stem, zone="z", settings=cfg)
    grid = tiling.TileGrid(wb, size)
    return w, x_cut, wb, cfg, caches, f"{grid.shape[0] - 1}_0"


@pytest.mark.shared
def test_a_tile_gathered_a_chunk_at_a_time_is_the_tile_gathered_at_once(tmp_path):
    """The caches are read a chunk at a time (never mapped whole): the tile, core and buffer
    from the neighbour, is the same whatever the chunk, to the bit and in the same order."""
    *_, cfg, caches, tid = two_blocks(tmp_path)
    gathered = [
        gather_tile("z", "west", tid, {b: BlockCache.open(d) for b, d in caches.items()}, cfg, chunk=chunk)
        for chunk in (10**9, 4096, 777)
    ]
    whole = gathered[0]
    assert whole.arrays["core"].any() and (whole.arrays["block_id"] == whole.meta["blocks"].index("east")).any()
    for t in gathered[1:]:
        assert t.meta == whole.meta
        for k, v in whole.arrays.items():
            assert t.arrays[k].dtype == v.dtype and np.array_equal(t.arrays[k], v), k


@pytest.mark.shared
def test_neighbour_block_buffer(tmp_path):
    w, x_cut, wb, cfg, caches, tid = two_blocks(tmp_path)
    preprocess_tile("z", "west", tid, caches, tmp_path / "t.npz", settings=cfg)
    t = load_tile(tmp_path / "t.npz")
    from_east = t["block_id"] == t.meta["blocks"].index("east")
    assert from_east.any(), "buffer points must come from the neighbouring block"
    assert not t["core"][from_east].any(), "a neighbour's points are never in this tile's core"
    xe = t["x"][from_east]
    assert xe.min() >= x_cut and xe.max() <= wb[2] + 40.0 + 1e-6 and xe.max() > x_cut + 35.0
    # the buffer's ground gets HAG ~0 too: the DTM spans the cut with the neighbour's ground
    ground = t["classification"] == 2
    assert np.median(np.abs(t["hag"][ground & from_east])) < 0.05
    expected = tiling.TileGrid(wb, cfg.tile_size).core_mask(np.asarray(w.x), np.asarray(w.y), tid).sum()
    assert t["core"].sum() == expected > 0


@pytest.mark.shared
def test_block_without_ground_is_classified_by_pdal(tmp_path):
    src = laspy.read(RGBNIR_BLOCK)
    truth_ground = np.asarray(src.classification) == 2
    src.classification = np.where(truth_ground, 1, src.classification)  # no class 2 at all
    noground = tmp_path / "noground.laz"
    src.write(noground)
    meta, tiles = run_block(tmp_path, noground, tile_size=200.0)
    assert meta["ground_source"] == "smrf"
    c = core_points(tiles)
    truth = truth_ground[c["point_index"]]
    # SMRF finds the same ground: true ground points get HAG ~0 and leave the model input
    assert np.median(np.abs(c["hag"][truth])) < 0.1
    assert (~c["model_input"][truth]).mean() > 0.9
    assert c["model_input"][~truth].mean() > 0.5


@pytest.mark.shared
def test_block_in_another_crs_than_its_zone(tmp_path):
    from pyproj import CRS

    from towerpipe.errors import InputError

    with pytest.raises(
        InputError,
        match=r"small\.laz: its CRS \(EPSG:2154\) differs from the rest of zone 'z' "
        r"\(EPSG:25831\); reproject it",
    ):
        split_block(
            RGBNIR_SMALL,
            tmp_path / "c",
            block="small",
            zone="z",
            zone_crs=CRS.from_epsg(25831).to_wkt(),
            settings=preprocess_settings(),
        )
