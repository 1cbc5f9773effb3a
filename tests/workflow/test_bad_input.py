"""The bad-input matrix (issue #6): every odd or broken block, through the real workflow.

Two zones are run once each with ``--keep-going``:

* zone ``A`` (the ``full`` feature set, no ``crs:`` key) holds one block per case, each
  derived from a 100 m square of a real IGN tile (RGB, NIR, extra
  bytes, ~9 pts/m²) and moved to its own place so that cases do not share
  buffers. The broken blocks must fail with a one-line error naming the file and the
  cause; every other block must complete; the zone is published as INCOMPLETE and its QA
  index names each failed block and why.
* zone ``B`` (the ``geometry`` feature set, ``crs:`` set) holds LAS 1.2 point formats
  0-3 without a CRS: all complete.

The model is randomly initialised and the gate is 1.0 (no window passes): these are
plumbing tests, the towers themselves are covered by ``test_e2e``.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import uuid

import laspy
import numpy as np
import pyogrio
import pytest
import yaml
from laspy.vlrs.vlrlist import VLRList

from conftest import REPO, RGBNIR_BLOCK

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]

#: Blocks of zone A that must fail: block name -> regex of the one-line error. A block
#: that cannot be split is recorded (its neighbours go on without its points) and fails
#: at its next own step; a model that needs missing dimensions fails at inference.
FAILING = {
    "not_las": r"InputError: .*not_las\.laz: not a readable LAS/LAZ file",
    "truncated": r"InputError: .*truncated\.laz: trunc",
    "no_crs": r"InputError: .*no_crs\.laz: no CRS in the file; set it in the config: `zones: \{{zone}: \{crs",
    "other_crs": r"InputError: .*other_crs\.laz: its CRS \(EPSG:25831\) differs from the rest of zone",
    "no_colour": r"ModelError: block 'no_colour' has no valid nir, rgb but model .* needs it; set `inference.model: auto`",
}
#: Blocks of zone A that must complete.
PASSING = ["good", "colour_8bit", "no_ground", "duplicates", "outliers", "dense", "f2__upper_case"]
#: Zone B: LAS 1.2 point formats without RGB/NIR (0, 1) or without NIR (2, 3), no CRS.
LEGACY = [f"las12_pf{pf}" for pf in range(4)]


def _run(*args):
    return subprocess.run([sys.executable, "-m", "snakemake", *args], cwd=REPO, capture_output=True, text=True)


def _moved(las: laspy.LasData, i: int) -> laspy.LasData:
    """A copy of ``las`` shifted 200 m east per case (100 m apart: no shared buffers)."""
    out = _subset(las, np.arange(len(las.points)))
    out.x = np.asarray(las.x) + 200.0 * i
    return out


def _subset(las: laspy.LasData, keep: np.ndarray) -> laspy.LasData:
    out = laspy.LasData(las.header.copy())
    out.points = las.points[keep]
    return out


def _drop_crs(las: laspy.LasData) -> None:
    """Remove the CRS records (WKT and GeoTIFF keys) of a file, keeping every other VLR."""
    crs_ids = {2112, 34735, 34736, 34737}
    las.header.vlrs = VLRList(v for v in las.header.vlrs if v.record_id not in crs_ids)
    las.header.evlrs = VLRList(v for v in (las.header.evlrs or []) if v.record_id not in crs_ids)
    las.header.global_encoding.wkt = False


def _write_zone_a(src: laspy.LasData, d):
    d.mkdir()
    cases = {}
    good = _moved(src, 0)
    good.add_extra_dim(laspy.ExtraBytesParams(name="reflectance_db", type=np.float32, description="extra dim"))
    good.reflectance_db = np.linspace(-20, 5, len(good.points)).astype(np.float32)
    cases["good"] = good
    c8 = _moved(src, 1)
    for band in ("red", "green", "blue", "nir"):
        setattr(c8, band, np.asarray(getattr(c8, band)) >> 8)
    cases["colour_8bit"] = c8
    ng = _moved(src, 2)
    cls = np.asarray(ng.classification).copy()
    cls[cls == 2] = 1
    ng.classification = cls
    cases["no_ground"] = ng
    dup = _moved(src, 3)
    cases["duplicates"] = _subset(dup, np.repeat(np.arange(len(dup.points)), 2))
    out = _moved(src, 4)
    z = np.asarray(out.z).copy()
    z[::5000] += 3000.0  # birds / atmospheric returns, km above the ground
    z[2500::5000] -= 800.0  # multipath, far below the ground
    out.z = z
    cases["outliers"] = out
    dense = _moved(src, 5)
    reps = 10
    dense = _subset(dense, np.repeat(np.arange(len(dense.points)), reps))
    rng = np.random.default_rng(0)
    dense.x = np.asarray(dense.x) + rng.normal(0, 0.15, len(dense.points))
    dense.y = np.asarray(dense.y) + rng.normal(0, 0.15, len(dense.points))
    cases["dense"] = dense
    for name, las in cases.items():
        las.write(d / f"{name}.laz")
    (d / "f2").mkdir()
    _moved(src, 6).write(d / "f2" / "upper_case.LAZ")
    # broken ones
    (d / "not_las.laz").write_text("id,x,y,z\n1,2,3,4\n" * 200)
    data = (d / "good.laz").read_bytes()
    (d / "truncated.laz").write_bytes(data[: len(data) // 3])
    _subset(_moved(src, 8), np.zeros(0, dtype=np.int64)).write(d / "empty.laz")
    nocrs = _moved(src, 9)
    _drop_crs(nocrs)
    nocrs.write(d / "no_crs.laz")
    from pyproj import CRS

    other = _moved(src, 10)
    _drop_crs(other)
    other.header.add_crs(CRS.from_epsg(25831))
    other.write(d / "other_crs.laz")
    # a LAS 1.4 point format 6 block (no RGB, no NIR) for a model that needs them
    pf6 = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    m = _moved(src, 11)
    pf6.header.offsets, pf6.header.scales = m.header.offsets, m.header.scales
    pf6.header.add_crs(m.header.parse_crs())
    pf6.header.global_encoding.wkt = True
    for dim in ("x", "y", "z", "intensity", "classification", "return_number", "number_of_returns", "gps_time"):
        setattr(pf6, dim, np.asarray(getattr(m, dim)))
    pf6.write(d / "no_colour.laz")


def _write_zone_b(src: laspy.LasData, d):
    d.mkdir()
    for pf in range(4):
        m = _moved(src, 20 + pf)
        las = laspy.LasData(laspy.LasHeader(point_format=pf, version="1.2"))
        las.header.offsets, las.header.scales = m.header.offsets, m.header.scales
        dims = ["x", "y", "z", "intensity", "return_number", "number_of_returns"]
        dims += ["gps_time"] if pf in (1, 3) else []
        dims += ["red", "green", "blue"] if pf in (2, 3) else []
        for dim in dims:
            setattr(las, dim, np.asarray(getattr(m, dim)))
        cls = np.asarray(m.classification)
        las.classification = np.where(cls > 31, 1, cls)  # 5-bit classes in formats 0-5
        las.write(d / f"las12_pf{pf}.las")


@pytest.fixture(scope="module")
def matrix(tmp_path_factory, random_model_factory):
    tmp = tmp_path_factory.mktemp("badinput")
    full = laspy.read(RGBNIR_BLOCK)
    x, y = np.asarray(full.x), np.asarray(full.y)
    x0, y0 = np.floor(x.max()) - 150, np.floor(y.max()) - 160  # a fully covered square
    src = _subset(full, np.flatnonzero((x >= x0) & (x < x0 + 100) & (y >= y0) & (y < y0 + 100)))
    _write_zone_a(src, tmp / "in_a")
    _write_zone_b(src, tmp / "in_b")
    za, zb = (f"pytest_bad_{k}_{uuid.uuid4().hex[:6]}" for k in "ab")
    cfg = {
        "zones": {za: {"input": str(tmp / "in_a")}, zb: {"input": str(tmp / "in_b"), "crs": "EPSG:2154"}},
        "workdir": str(tmp / "work"),
        "inference": {"gate": 1.0},
    }
    (tmp / "a.yaml").write_text(
        yaml.safe_dump({**cfg, "inference": {"gate": 1.0, "model": str(random_model_factory("full"))}})
    )
    (tmp / "b.yaml").write_text(
        yaml.safe_dump({**cfg, "inference": {"gate": 1.0, "model": str(random_model_factory("geometry"))}})
    )
    pa = _run("--cores", "2", "--keep-going", f"results/{za}/", f"--configfile={tmp / 'a.yaml'}")
    pb = _run("--cores", "2", "--keep-going", f"results/{zb}/", f"--configfile={tmp / 'b.yaml'}")
    yield {"a": (za, pa, tmp / "in_a"), "b": (zb, pb, tmp / "in_b"), "work": tmp / "work"}
    for z in (za, zb):
        shutil.rmtree(REPO / "results" / z, ignore_errors=True)


@pytest.mark.shared
def test_the_matrix_runs_at_least_14_cases_each_a_block(matrix):
    from towerpipe.io.inputs import block_ids

    cases = set(FAILING) | set(PASSING) | set(LEGACY)
    assert len(cases) >= 14
    blocks = set()
    for zone, _, _ in (matrix["a"], matrix["b"]):
        blocks |= set(block_ids(sorted(json.loads((matrix["work"] / zone / "inputs.json").read_text()))))
    assert cases <= blocks, sorted(cases - blocks)


@pytest.mark.parametrize("block", sorted(FAILING))
@pytest.mark.shared
def test_broken_block_fails_alone_with_a_one_line_reason(matrix, block):
    zone, proc, _ = matrix["a"]
    assert proc.returncode != 0
    pattern = FAILING[block].replace("{zone}", re.escape(zone))
    logs = matrix["work"] / zone / "logs"
    text = "".join(p.read_text() for p in sorted(logs.glob(f"*/{block}.log")) + sorted(logs.glob(f"*/{block}/*.log")))
    assert re.search(pattern, text), text[-2000:]
    out = REPO / "results" / zone
    incomplete = (out / "INCOMPLETE.txt").read_text()
    line = next((ln for ln in incomplete.splitlines() if ln.strip().startswith(f"{block}:")), None)
    assert line is not None and re.search(pattern, line), incomplete
    assert block in (out / "qa" / "index.html").read_text()
    assert not (out / "blocks" / f"{block}.laz").exists()


@pytest.mark.shared
def test_a_file_of_zero_points_is_listed_never_failed(matrix):
    """A readable file without points (a sea tile) has nothing to process: the zone's QA index
    lists it among the blocks that need a look, and it is neither run nor a failure."""
    zone, _, _ = matrix["a"]
    out = REPO / "results" / zone
    index = json.loads((out / "qa" / "index.json").read_text())
    (row,) = [b for b in index["blocks"] if b["block"] == "empty"]
    assert row["status"] == "look" and row["codes"] == ["empty"]
    assert row["reasons"] == [
        "empty.laz: the file holds zero points: nothing to process; skipped while it is in the zone, never a failure"
    ]
    assert "empty:" not in (out / "INCOMPLETE.txt").read_text()  # the zone is incomplete for the others
    assert not (out / "blocks" / "empty.laz").exists() and not (matrix["work"] / zone / "cache" / "empty").exists()


@pytest.mark.shared
def test_unreadable_neighbour_costs_only_itself(matrix):
    # truncated.laz overlaps good.laz (same place, a third of its bytes): good completes,
    # without buffer points from it, and its QA says so
    zone, _, _ = matrix["a"]
    qa = json.loads((REPO / "results" / zone / "qa" / "good.json").read_text())
    assert any("neighbour block truncated could not be read" in w for w in qa["warnings"]), qa["warnings"]


@pytest.mark.parametrize("block", PASSING)
@pytest.mark.shared
def test_odd_block_completes_with_every_point(matrix, block):
    zone, _, indir = matrix["a"]
    out = REPO / "results" / zone
    src = indir / (f"{block}.laz" if "__" not in block else "f2/upper_case.LAZ")
    a, b = laspy.read(src), laspy.read(out / "blocks" / f"{block}.laz")
    assert len(a.points) == len(b.points)
    # every byte of every point record but the class, extra bytes included
    ra, rb = a.points.array.copy(), b.points.array.copy()
    ra["classification"], rb["classification"] = 0, 0
    size = ra.dtype.itemsize
    np.testing.assert_array_equal(
        ra.view(np.uint8).reshape(len(ra), -1), rb.view(np.uint8).reshape(len(rb), -1)[:, :size]
    )
    assert a.header.parse_crs() == b.header.parse_crs()
    assert "TowerProbability" in b.point_format.dimension_names
    # no towers: a valid, empty layer
    towers = pyogrio.read_dataframe(out / "towers" / f"{block}.gpkg", layer="towers")
    assert len(towers) == 0
    qa = json.loads((out / "qa" / f"{block}.json").read_text())
    assert qa["points"] == len(a.points)


@pytest.mark.shared
def test_specific_handling(matrix):
    zone, _, indir = matrix["a"]
    out = REPO / "results" / zone
    qa = {b: json.loads((out / "qa" / f"{b}.json").read_text()) for b in PASSING}
    assert qa["colour_8bit"]["stats"]["color_bits"] == 8 and qa["good"]["stats"]["color_bits"] == 16
    assert qa["no_ground"]["ground_classified"] and not qa["good"]["ground_classified"]
    # no class 2 in the input; PDAL classified the ground and the QA reports that share
    assert qa["no_ground"]["stats"]["ground_fraction"] == 0 and qa["no_ground"]["ground_ratio"] > 0.5
    # km-high and km-deep returns are noise: out of the model input, kept in the block
    counts = qa["outliers"]["stats"]["counts"]
    assert counts["noise_hag_core"] >= 2 * (qa["outliers"]["points"] // 5000) - 2
    # the extra dimension survives with its values
    b = laspy.read(out / "blocks" / "good.laz")
    np.testing.assert_array_equal(b.reflectance_db, laspy.read(indir / "good.laz").reflectance_db)
    # >= 50 points per m² went through
    assert qa["dense"]["density"]["density_median"] >= 50
    # the whole zone's GeoPackage exists with an empty towers layer
    assert len(pyogrio.read_dataframe(out / "towers.gpkg", layer="towers")) == 0


@pytest.mark.parametrize("block", LEGACY)
@pytest.mark.shared
def test_las12_formats_without_colour_or_crs(matrix, block):
    zone, proc, indir = matrix["b"]
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = REPO / "results" / zone
    assert not (out / "INCOMPLETE.txt").exists()
    a, b = laspy.read(indir / f"{block}.las"), laspy.read(out / "blocks" / f"{block}.laz")
    assert len(a.points) == len(b.points)
    np.testing.assert_array_equal(np.asarray(a.x), np.asarray(b.x))
    assert b.header.parse_crs().to_epsg() == 2154  # the zone's crs: key filled it in
