"""Reading blocks: bad input gives one line naming the file and the cause."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from pyproj import CRS

from conftest import RGBNIR_SMALL
from towerpipe.errors import InputError
from towerpipe.io.inputs import find_blocks
from towerpipe.io.las import las_header_for, read_block, read_header


def write_points(path, n=100, *, crs="EPSG:25831", point_format=8, version="1.4", colour_max=65535):
    rng = np.random.default_rng(0)
    if version == "1.4":
        header = las_header_for(point_format=point_format, crs_wkt=None, offsets=(400000, 4600000, 0))
        if crs:
            from pyproj import CRS

            header.add_crs(CRS.from_user_input(crs))
            header.global_encoding.wkt = True
    else:
        header = laspy.LasHeader(point_format=point_format, version=version)
        header.offsets = np.array([400000.0, 4600000.0, 0.0])
        header.scales = np.array([0.01, 0.01, 0.01])
    las = laspy.LasData(header)
    las.x = 400000 + rng.uniform(0, 50, n)
    las.y = 4600000 + rng.uniform(0, 50, n)
    las.z = 100 + rng.uniform(0, 5, n)
    if "red" in las.point_format.dimension_names:
        las.red = rng.integers(0, colour_max + 1, n)
    las.write(path)
    return path


@pytest.mark.shared
def test_reads_real_block():
    blk = read_block(RGBNIR_SMALL)
    assert len(blk) == 37805
    assert blk.has_rgb and blk.has_nir and blk.color_bits == 16
    assert "Lambert" in blk.crs_wkt or "RGF93" in blk.crs_wkt
    assert blk.columns["x"].dtype == np.float64


def test_not_a_las_file(tmp_path):
    p = tmp_path / "notes.laz"
    p.write_text("this is not a point cloud\n" * 20)
    with pytest.raises(InputError, match=r"notes\.laz: not a readable LAS/LAZ file"):
        read_header(p)


def test_truncated_laz(tmp_path):
    good = write_points(tmp_path / "good.laz", n=20000)
    data = good.read_bytes()
    bad = tmp_path / "cut.laz"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.laz: trunc"):
        read_block(bad)


def test_zero_points(tmp_path):
    p = write_points(tmp_path / "empty.las", n=0)
    with pytest.raises(InputError, match=r"empty\.las: the file holds zero points"):
        read_block(p)


def test_missing_crs_names_the_config_key(tmp_path):
    p = write_points(tmp_path / "nocrs.laz", crs=None)
    with pytest.raises(InputError, match=r"nocrs\.laz: no CRS in the file; set it in the config: .*zones: \{z1: \{crs"):
        read_block(p, zone="z1")
    blk = read_block(p, crs="EPSG:25831", zone="z1")
    assert "ETRS89" in blk.crs_wkt


def test_bad_crs_override(tmp_path):
    p = write_points(tmp_path / "b.laz", crs=None)
    with pytest.raises(InputError, match=r"zones\.z1\.crs"):
        read_block(p, crs="EPSG:not-a-code", zone="z1")


def test_a_file_keeps_its_own_crs(tmp_path):
    """The zone's ``crs`` is for files without one: a file's own CRS is kept, one in another plan
    CRS is refused (naming both, the key and the fix), a vertical datum the key lacks is kept."""
    p = write_points(tmp_path / "own.laz", crs="EPSG:25831")
    assert CRS.from_wkt(read_block(p, crs="EPSG:25831", zone="z1").crs_wkt).to_epsg() == 25831
    with pytest.raises(
        InputError,
        match=r"own\.laz: its CRS \(EPSG:25831\) differs from config key `zones\.z1\.crs` \(EPSG:25830\).*a_srs",
    ) as exc:
        read_block(p, crs="EPSG:25830", zone="z1")
    assert "\n" not in str(exc.value)
    q = write_points(tmp_path / "compound.laz", crs="EPSG:25831+5782")
    kept = CRS.from_wkt(read_block(q, crs="EPSG:25831", zone="z1").crs_wkt)
    assert kept.is_compound and kept.sub_crs_list[0].to_epsg() == 25831


def test_las12_without_colour(tmp_path):
    p = write_points(tmp_path / "old.las", point_format=1, version="1.2", crs=None)
    blk = read_block(p, crs="EPSG:25831")
    assert not blk.has_rgb and not blk.has_nir
    assert blk.columns["red"].sum() == 0


def test_8bit_colour_in_16bit_fields(tmp_path):
    p = write_points(tmp_path / "c8.laz", colour_max=255)
    assert read_block(p).color_bits == 8


def test_find_blocks_with_flight_subfolders(tmp_path):
    (tmp_path / "f1").mkdir()
    write_points(tmp_path / "f1" / "a.laz")
    write_points(tmp_path / "b.LAS")
    (tmp_path / "readme.txt").write_text("x")
    assert list(find_blocks(tmp_path)) == ["b", "f1__a"]


def test_crs_units_refused_naming_the_unit():
    import pytest
    from pyproj import CRS

    from towerpipe.errors import InputError
    from towerpipe.io.las import check_metric_crs

    for ok in ("EPSG:25831", "EPSG:2154+5720", "EPSG:7415"):
        check_metric_crs("b.laz", CRS.from_user_input(ok).to_wkt())
    for crs, msg in (
        ("EPSG:2263", "horizontal unit 'US survey foot'"),
        ("EPSG:4326", "horizontal unit 'degree'"),
        ("EPSG:25831+6360", "vertical unit 'US survey foot'"),
        ("EPSG:2227", "US survey foot"),
    ):
        with pytest.raises(InputError, match=msg) as exc:
            check_metric_crs("b.laz", CRS.from_user_input(crs).to_wkt(), zone="z", from_config=True)
        assert "\n" not in str(exc.value) and "zones.z.crs" in str(exc.value)
