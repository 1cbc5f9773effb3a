"""Tests of towerpipe.products.merge: every input point, every byte but Classification, kept."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from laspy.vlrs.known import ExtraBytesVlr, LasZipVlr
from laspy.vlrs.vlrlist import VLRList

from conftest import BACKGROUNDS, preprocess_settings, write_pred
from towerpipe.errors import InputError, TowerpipeError
from towerpipe.io.lasformat import OWN_DIMENSIONS, PROB_DIMENSION, TOWER_ID_DIMENSION, own_dimensions
from towerpipe.products.merge import merge_block

# ----------------------------------------------------------------------------- helpers


def raw_bytes(las: laspy.LasData) -> np.ndarray:
    arr = las.points.array
    return arr.view(np.uint8).reshape(len(arr), arr.dtype.itemsize)


def class_offset(las: laspy.LasData) -> int:
    dt = las.points.array.dtype
    name = "classification" if las.header.point_format.id >= 6 else "raw_classification"
    return dt.fields[name][1]


def vlr_key(v) -> tuple:
    return (v.user_id, v.record_id, v.description, bytes(v.record_data_bytes()))


def assert_invariant(
    inp: Path, out: Path, expected_prob: np.ndarray, threshold: float = 0.5, expected_ids: np.ndarray | None = None
) -> None:
    """Everything but Classification bit for bit; classes, probabilities and tower ids as specified."""
    a = laspy.read(inp)
    b = laspy.read(out)
    ha, hb = a.header, b.header
    assert hb.point_count == ha.point_count == len(expected_prob)
    assert (hb.version, hb.point_format.id) == (ha.version, ha.point_format.id)
    np.testing.assert_array_equal(hb.scales, ha.scales)
    np.testing.assert_array_equal(hb.offsets, ha.offsets)
    np.testing.assert_array_equal(hb.mins, ha.mins)
    np.testing.assert_array_equal(hb.maxs, ha.maxs)
    assert hb.file_source_id == ha.file_source_id
    assert hb.system_identifier == ha.system_identifier
    assert hb.creation_date == ha.creation_date
    assert hb.global_encoding.value | 16 == ha.global_encoding.value | 16
    assert hb.number_of_points_by_return.tolist() == ha.number_of_points_by_return.tolist()

    # point records: the input bytes are a prefix of the output bytes, except classification;
    # then the probability (float32) and the tower id (uint64)
    ra, rb = raw_bytes(a), raw_bytes(b)
    size_a = ra.shape[1]
    assert rb.shape[1] == size_a + 4 + 8
    co = class_offset(a)
    keep = np.ones(size_a, bool)
    keep[co] = False
    assert np.array_equal(rb[:, :size_a][:, keep], ra[:, keep])
    if ha.point_format.id < 6:  # flags in the high bits of the 1.2 class byte kept
        assert np.array_equal(rb[:, co] & 0xE0, ra[:, co] & 0xE0)
    # every named input dimension (incl. extra bytes) identical, except classification
    for name in a.point_format.dimension_names:
        if name in ("classification", "raw_classification") or name not in b.point_format.dimension_names:
            continue
        assert np.array_equal(np.asarray(a[name]), np.asarray(b[name])), name

    # classes, probability and tower id (the two new dimensions, last, in this order)
    assert list(b.point_format.extra_dimension_names)[-2:] == [PROB_DIMENSION, TOWER_ID_DIMENSION]
    prob = np.asarray(b[PROB_DIMENSION])
    assert prob.dtype == np.float32
    np.testing.assert_array_equal(prob, expected_prob.astype(np.float32))
    ids = np.asarray(b[TOWER_ID_DIMENSION])
    assert ids.dtype == np.uint64
    np.testing.assert_array_equal(ids, np.zeros(len(ids), np.uint64) if expected_ids is None else expected_ids)
    assert np.array_equal(rb[:, size_a : size_a + 4].copy().view(np.float32).ravel(), prob)
    cls_in = np.asarray(a.classification)
    want = np.where(expected_prob >= threshold, 15, np.where(cls_in == 15, 1, cls_in))
    # a withheld point ("not to be included in processing") keeps its class, 15 included
    want = np.where(np.asarray(a.withheld, bool), cls_in, want)
    np.testing.assert_array_equal(np.asarray(b.classification), want)

    # VLRs: all but the Extra Bytes / LAZ ones identical and in order; EB descriptors kept
    va = [vlr_key(v) for v in ha.vlrs if not isinstance(v, (ExtraBytesVlr, LasZipVlr))]
    vb = [vlr_key(v) for v in hb.vlrs if not isinstance(v, (ExtraBytesVlr, LasZipVlr))]
    assert va == vb
    eb_a = b"".join(bytes(v.record_data_bytes()) for v in ha.vlrs if isinstance(v, ExtraBytesVlr))
    eb_b = [v for v in hb.vlrs if isinstance(v, ExtraBytesVlr)]
    assert len(eb_b) == 1
    data_b = bytes(eb_b[0].record_data_bytes())
    assert data_b[: len(eb_a)] == eb_a and len(data_b) == len(eb_a) + 2 * 192
    prob_struct, id_struct = eb_b[0].extra_bytes_structs[-2:]
    assert prob_struct.name == PROB_DIMENSION.encode() and id_struct.name == TOWER_ID_DIMENSION.encode()
    assert prob_struct.min_is_relevant() and prob_struct.max_is_relevant()
    assert float(prob_struct._raw_min()[0]) == pytest.approx(float(expected_prob.min()))
    assert float(prob_struct._raw_max()[0]) == pytest.approx(float(expected_prob.max()))
    assert int(id_struct._raw_max()[0]) == int(ids.max())
    # EVLRs
    ea = [vlr_key(v) for v in (ha.evlrs or [])]
    eb = [vlr_key(v) for v in (hb.evlrs or [])]
    assert ea == eb
    # CRS and the WKT bit
    if ha.parse_crs() is not None:
        assert hb.parse_crs() == ha.parse_crs()
    if hb.version.minor >= 4 and any(type(v).__name__ == "WktCoordinateSystemVlr" for v in hb.vlrs):
        assert hb.global_encoding.wkt


def make_las(
    path: Path,
    *,
    version: str,
    point_format: int,
    n: int,
    seed: int = 0,
    crs: str | None = "EPSG:25831",
    extra: bool = False,
    evlr: bool = False,
) -> Path:
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.01, 0.01, 0.001])
    header.offsets = np.array([400000.0, 4600000.0, 0.0])
    header.system_identifier = "towerpipe test"
    if extra:
        header.add_extra_dims(
            [laspy.ExtraBytesParams("TowerId", "uint32"), laspy.ExtraBytesParams("Amp", "float64", scales=None)]
        )
    if crs is not None:
        import pyproj

        header.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(header)
    las.x = 400000 + rng.uniform(0, 500, n)
    las.y = 4600000 + rng.uniform(0, 500, n)
    las.z = rng.uniform(100, 160, n)
    las.intensity = rng.integers(0, 65535, n, dtype=np.uint16)
    las.return_number = rng.integers(1, 4, n, dtype=np.uint8)
    las.number_of_returns = np.maximum(las.return_number, rng.integers(1, 4, n, dtype=np.uint8))
    las.classification = rng.choice(np.array([1, 2, 3, 5, 6, 15], np.uint8), n)
    las.synthetic = rng.random(n) < 0.1
    las.withheld = rng.random(n) < 0.05
    if "gps_time" in las.point_format.dimension_names:
        las.gps_time = np.sort(rng.uniform(0, 1e5, n))
    if "red" in las.point_format.dimension_names:
        las.red = rng.integers(0, 65535, n, dtype=np.uint16)
    if extra:
        las.TowerId = rng.integers(0, 9, n, dtype=np.uint32)
        las.Amp = rng.normal(size=n)
    if evlr:
        las.evlrs = VLRList([laspy.VLR("towerpipe", 42, "test evlr", b"\x01\x02\x03payload" * 10)])
    las.write(path)
    return path


# ----------------------------------------------------------------------------- files


@pytest.mark.parametrize("version,pf", [("1.2", 1), ("1.2", 3), ("1.2", 0), ("1.4", 6), ("1.4", 7), ("1.4", 8)])
def test_merge_generated_formats(tmp_path, version, pf):
    n = 20_000
    src = make_las(tmp_path / "b.laz", version=version, point_format=pf, n=n, extra=(pf in (3, 8)), evlr=(pf == 6))
    rng = np.random.default_rng(1)
    idx = rng.choice(n, 3000, replace=False)
    p = rng.random(3000).astype(np.float32)
    half = 1500
    preds = [
        write_pred(tmp_path / "t1.npz", "b", idx[:half], p[:half]),
        write_pred(tmp_path / "t2.npz", "b", idx[half:], p[half:]),
    ]
    out = tmp_path / "out" / "b.laz"
    stats = merge_block(src, preds, out, threshold=0.5, chunk_size=7_000)
    expected = np.zeros(n, np.float32)
    expected[idx] = p
    assert_invariant(src, out, expected)
    assert stats["points"] == n
    withheld = np.asarray(laspy.read(src).withheld, bool)
    assert stats["tower_points"] == int(((expected >= 0.5) & ~withheld).sum())
    cls_in = np.asarray(laspy.read(src).classification)
    assert stats["input_tower_points"] == int((cls_in == 15).sum())
    assert stats["relabelled_15_to_1"] == int(((cls_in == 15) & (expected < 0.5) & ~withheld).sum())
    assert not (out.parent / "b.laz.part").exists()
    assert laspy.open(out).header.are_points_compressed


def test_merge_without_predictions_only_demotes_input_towers(tmp_path):
    src = make_las(tmp_path / "b.las", version="1.2", point_format=1, n=5000)
    out = tmp_path / "b_out.laz"
    stats = merge_block(src, [], out, threshold=0.5)
    assert_invariant(src, out, np.zeros(5000, np.float32))
    cls_in = np.asarray(laspy.read(src).classification)
    withheld = np.asarray(laspy.read(src).withheld, bool)
    assert stats["relabelled_15_to_1"] == int(((cls_in == 15) & ~withheld).sum()) > 0
    assert stats["tower_points"] == 0


def test_merge_adds_crs_when_missing(tmp_path):
    src = make_las(tmp_path / "b.laz", version="1.4", point_format=6, n=1000, crs=None)
    out = tmp_path / "o.laz"
    merge_block(src, [], out, threshold=0.5, crs="EPSG:25831")
    h = laspy.open(out).header
    assert h.parse_crs().to_epsg() == 25831
    assert h.global_encoding.wkt


def test_merge_rejects_bad_threshold(tmp_path):
    src = make_las(tmp_path / "b.laz", version="1.4", point_format=6, n=1000)
    with pytest.raises(TowerpipeError):
        merge_block(src, [], tmp_path / "o.laz", threshold=0.0)


@pytest.mark.parametrize("version,pf", [("1.2", 3), ("1.4", 8)])
def test_own_output_is_reprocessed_values_replaced(tmp_path, version, pf):
    """A classified block as input: the same layout and descriptors, the values replaced; merging
    it again with the same predictions and towers gives the same file, byte for byte."""
    from towerpipe.io.members import save_members

    n = 6000
    src = make_las(tmp_path / "b.laz", version=version, point_format=pf, n=n, extra=True)
    rng = np.random.default_rng(4)
    idx = rng.choice(n, 900, replace=False)
    pred = write_pred(tmp_path / "t.npz", "b", idx, np.full(900, 0.9, np.float32))
    save_members(tmp_path / "m.npz", {40000004600000: (np.array(["b"] * 400, dtype=object), idx[:400])})
    first = merge_block(src, [pred], tmp_path / "o1.laz", threshold=0.5, tower_points=[tmp_path / "m.npz"])
    assert not first["reprocessed"] and own_dimensions(tmp_path / "o1.laz") == list(OWN_DIMENSIONS)
    again = merge_block(
        tmp_path / "o1.laz", [pred], tmp_path / "o2.laz", threshold=0.5, tower_points=[tmp_path / "m.npz"]
    )
    assert again["reprocessed"] and again["towers"] == 1
    assert (tmp_path / "o2.laz").read_bytes() == (tmp_path / "o1.laz").read_bytes()
    # new predictions and no towers: the values are replaced in place, nothing else changes
    other = write_pred(tmp_path / "t2.npz", "b", idx[:10], np.full(10, 0.3, np.float32))
    merge_block(tmp_path / "o1.laz", [other], tmp_path / "o3.laz", threshold=0.5)
    expected = np.zeros(n, np.float32)
    expected[idx[:10]] = 0.3
    a, c = laspy.read(tmp_path / "o1.laz"), laspy.read(tmp_path / "o3.laz")
    assert list(c.point_format.dimension_names) == list(a.point_format.dimension_names)
    np.testing.assert_array_equal(np.asarray(c[PROB_DIMENSION]), expected)
    assert not np.asarray(c[TOWER_ID_DIMENSION]).any()
    # nothing classified 15 but the withheld points the input held as 15 (never processed)
    assert np.array_equal(np.asarray(c.classification) == 15, (np.asarray(c.classification) == 15) & c.withheld)
    for name in a.point_format.dimension_names:
        if name not in ("classification", "raw_classification", PROB_DIMENSION, TOWER_ID_DIMENSION):
            assert np.array_equal(np.asarray(a[name]), np.asarray(c[name])), name


@pytest.mark.parametrize(
    "name,dtype,scaled",
    [(PROB_DIMENSION, "int32", False), (TOWER_ID_DIMENSION, "uint32", False), (PROB_DIMENSION, "float32", True)],
)
def test_a_foreign_dimension_with_towerpipes_name_is_refused(tmp_path, name, dtype, scaled):
    """Same name, another type (or scaled): somebody else's dimension, refused at the split."""
    from towerpipe.preprocess.split import split_block

    header = laspy.LasHeader(point_format=6, version="1.4")
    scale = {"scales": np.array([0.5]), "offsets": np.array([0.0])} if scaled else {}
    header.add_extra_dims([laspy.ExtraBytesParams(name, dtype, **scale)])
    import pyproj

    header.add_crs(pyproj.CRS.from_epsg(25831))
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.arange(10.0) + 4e5, np.arange(10.0) + 4.6e6, np.arange(10.0)
    las.write(tmp_path / "f.laz")
    with pytest.raises(InputError, match=rf"f\.laz.*{name}.*rename or remove"):
        split_block(tmp_path / "f.laz", tmp_path / "cache", block="f", crs="EPSG:25831", settings=preprocess_settings())
    meta = split_block(
        tmp_path / "f.laz",
        tmp_path / "cache",
        block="f",
        crs="EPSG:25831",
        settings=preprocess_settings(),
        record_errors=True,
    )
    assert meta["error"]["type"] == "InputError" and name in meta["error"]["cause"]
    with pytest.raises(InputError, match=name):
        merge_block(tmp_path / "f.laz", [], tmp_path / "o.laz", threshold=0.5)


@pytest.mark.shared
@pytest.mark.parametrize("name", ["ign_rgbnir_block.laz", "ign_high_noise.laz", "ign_rgb_subset.laz", "ign_bridge.laz"])
def test_merge_real_blocks_invariant(tmp_path, name):
    src = BACKGROUNDS / name
    n = laspy.open(src).header.point_count
    rng = np.random.default_rng(7)
    idx = rng.choice(n, min(n, 20_000), replace=False)
    p = rng.random(len(idx)).astype(np.float32)
    pred = write_pred(tmp_path / "t.npz", "blk", idx, p)
    out = tmp_path / "out.laz"
    merge_block(src, [pred], out, threshold=0.5, chunk_size=300_000)
    expected = np.zeros(n, np.float32)
    expected[idx] = p
    assert_invariant(src, out, expected)


@pytest.mark.shared
def test_merge_several_extra_byte_blocks_described_in_output(tmp_path):
    """The input has two Extra Bytes VLRs; both descriptors survive in the output."""
    src = BACKGROUNDS / "ign_rgbnir_block.laz"
    out = tmp_path / "out.laz"
    merge_block(src, [], out, threshold=0.5)
    names = list(laspy.open(out).header.point_format.extra_dimension_names)
    assert names == ["Deviation", "confidence", PROB_DIMENSION, TOWER_ID_DIMENSION]


@pytest.mark.parametrize("version,pf", [("1.2", 3), ("1.4", 8)])
def test_merge_from_split_records_equals_merge_from_laz(tmp_path, version, pf):
    """The split's copy of the point records gives the same file as decoding the LAZ again."""
    from towerpipe.io.blockcache import BlockCache
    from towerpipe.preprocess.split import split_block

    n = 12_000
    src = make_las(tmp_path / "b.laz", version=version, point_format=pf, n=n, extra=True)
    split_block(src, tmp_path / "cache", block="b", crs="EPSG:25831", settings=preprocess_settings())
    rng = np.random.default_rng(3)
    idx = rng.choice(n, 2000, replace=False)
    pred = write_pred(tmp_path / "t.npz", "b", idx, rng.random(2000).astype(np.float32))
    a, b = tmp_path / "a.laz", tmp_path / "b_out.laz"
    merge_block(src, [pred], a, threshold=0.5, chunk_size=5_000)
    merge_block(src, [pred], b, threshold=0.5, chunk_size=5_000, records=BlockCache(tmp_path / "cache").records_path)
    assert a.read_bytes() == b.read_bytes()


def test_merge_refuses_stale_records(tmp_path):
    src = make_las(tmp_path / "b.laz", version="1.4", point_format=6, n=1000)
    np.save(tmp_path / "records.npy", np.zeros((999, 30), np.uint8))
    with pytest.raises(InputError, match="split_block"):
        merge_block(src, [], tmp_path / "o.laz", threshold=0.5, records=tmp_path / "records.npy")
    assert not (tmp_path / "o.laz").exists()


def test_merge_with_tower_points_classifies_only_reported_towers(tmp_path):
    """Classification 15 on exactly the points of reported towers; TowerProbability as predicted."""
    from towerpipe.io.members import save_members

    n = 5000
    src = make_las(tmp_path / "b.laz", version="1.4", point_format=6, n=n)
    rng = np.random.default_rng(2)
    # predictions exist for processed points only: never for a withheld one
    idx = rng.choice(np.flatnonzero(~np.asarray(laspy.read(src).withheld, bool)), 800, replace=False)
    p = np.full(800, 0.95, np.float32)
    pred = write_pred(tmp_path / "t.npz", "b", idx, p)
    tower = idx[:300]  # the reported tower; the other 500 points were dropped
    save_members(tmp_path / "own.points.npz", {40000014600001: (np.array(["b"] * 300, dtype=object), tower)})
    # a neighbour's tower file naming other blocks only
    save_members(tmp_path / "nb.points.npz", {40000024600002: (np.array(["c"] * 5, dtype=object), np.arange(5))})
    out = tmp_path / "o.laz"
    stats = merge_block(
        src, [pred], out, threshold=0.5, tower_points=[tmp_path / "own.points.npz", tmp_path / "nb.points.npz"]
    )
    las = laspy.read(out)
    cls_in = np.asarray(laspy.read(src).classification)
    expected = np.where(cls_in == 15, 1, cls_in)
    expected[tower] = 15
    withheld = np.asarray(laspy.read(src).withheld, bool)  # never processed: their class is kept
    expected = np.where(withheld, cls_in, expected)
    np.testing.assert_array_equal(np.asarray(las.classification), expected)
    prob = np.zeros(n, np.float32)
    prob[idx] = p
    np.testing.assert_array_equal(np.asarray(las[PROB_DIMENSION]), prob)
    ids = np.zeros(n, np.uint64)
    ids[tower] = 40000014600001  # joinable to the GeoPackage's tower_id
    np.testing.assert_array_equal(np.asarray(las[TOWER_ID_DIMENSION]), ids)
    assert stats["tower_points"] == 300 and stats["points_above_threshold"] == 800 and stats["towers"] == 1


def test_every_las_version_and_point_format_is_accepted_at_split_and_merge():
    import pytest

    from towerpipe.errors import InputError
    from towerpipe.io.lasformat import SUPPORTED_FORMATS, check_format

    assert sum(len(v) for v in SUPPORTED_FORMATS.values()) == 2 + 4 + 6 + 11
    for (major, minor), pfs in SUPPORTED_FORMATS.items():
        for pf in pfs:
            check_format(f"{major}.{minor}", pf, "b.laz")
    for version, pf in (("1.2", 6), ("1.0", 0), ("1.4", 11)):
        with pytest.raises(InputError, match=f"LAS {version} point format {pf} is not a valid"):
            check_format(version, pf, "b.laz")
