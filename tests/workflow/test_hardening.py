"""Issue #16 through the real workflow: nothing stale, nothing silently wrong, nothing half-published.

Zones of generated blocks (the CI scene, cut and rewritten; no network, no real data):

* ``headers`` (the shipped model): the CI scene's blocks with a shrunken header and an
  absurd one (maxs off by 1.4e6 m), plus a truncated copy whose name sorts between them:
  the towers and every point must equal a plain run of the CI scene;
* ``names`` (a random model, no window passes: plumbing): file names that are not safe
  ids, two files of one block, CRSs in feet / degrees / feet of height, a block without
  NIR between NIR neighbours;
* ``formats`` (random geometry model): LAS 1.1, 1.3 and 1.4 point formats and a COPC
  file, then a nightly rerun (polled: ``results/<zone>/`` must exist at every moment)
  after one block is replaced by other content with an older mtime and another by a
  broken file;
* ``allbad``: every block broken.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import laspy
import markupsafe
import numpy as np
import pytest
from laspy.vlrs.vlrlist import VLRList
from pyproj import CRS

from conftest import CI_BLOCKS, REPO, same_points, snakemake_run, tower_features, write_zone_config

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]

#: Byte offsets of max x / min x / max y / min y in a LAS 1.x public header (doubles).
_MAX_X, _MIN_X, _MAX_Y, _MIN_Y = 179, 187, 195, 203


def _patch_header(path: Path, **values: float) -> None:
    """Overwrite header bounds in place (LAZ headers are not compressed)."""
    offsets = {"max_x": _MAX_X, "min_x": _MIN_X, "max_y": _MAX_Y, "min_y": _MIN_Y}
    with open(path, "r+b") as fh:
        for key, v in values.items():
            fh.seek(offsets[key])
            fh.write(struct.pack("<d", v))


def _zone(prefix: str) -> str:
    return f"pytest_{prefix}_{uuid.uuid4().hex[:6]}"


def _cut(src: Path, x0: float, y0: float, size: float, shift: tuple[float, float] = (0.0, 0.0)) -> laspy.LasData:
    """A square of a block, moved by ``shift`` (all attributes and VLRs kept)."""
    las = laspy.read(src)
    x, y = np.asarray(las.x), np.asarray(las.y)
    keep = (x >= x0) & (x < x0 + size) & (y >= y0) & (y < y0 + size)
    out = laspy.LasData(las.header.copy())
    out.points = las.points[keep]
    out.x = np.asarray(out.x) + shift[0]
    out.y = np.asarray(out.y) + shift[1]
    return out


def _with_crs(las: laspy.LasData, crs: str) -> laspy.LasData:
    las.header.vlrs = VLRList(v for v in las.header.vlrs if v.record_id not in {2112, 34735, 34736, 34737})
    las.header.add_crs(CRS.from_user_input(crs))
    return las


def _log_text(work: Path, zone: str, block: str) -> str:
    logs = work / zone / "logs"
    return "".join(p.read_text() for p in sorted(logs.glob(f"*/{block}.log")) + sorted(logs.glob(f"*/{block}/*.log")))


def _split_log(work: Path, zone: str, block: str) -> str:
    """What the job that split the block logged about it: its own log, or its split batch's lines
    that name it (rule split_batch)."""
    logs = work / zone / "logs"
    own = logs / "split_block" / f"{block}.log"
    if own.exists():
        return own.read_text()
    lines = [ln for p in sorted((logs / "split_batch").glob("*.log")) for ln in p.read_text().splitlines()]
    return "\n".join(ln for ln in lines if f"block {block}: " in ln)


def _leftovers(*roots: Path) -> list[str]:
    return [
        str(p)
        for r in roots
        if r.exists()
        for p in r.rglob("*")
        if p.name.endswith((".part", ".staging", ".old")) or ".part." in p.name
    ]


# --------------------------------------------------------------------------- headers


@pytest.fixture(scope="module")
def headers_run(ci_scene, ci_reference, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("headers")
    indir = tmp / "in"
    indir.mkdir()
    a, b = (indir / f"{n}.laz" for n in CI_BLOCKS)
    shutil.copy(ci_scene / a.name, a)
    shutil.copy(ci_scene / b.name, b)
    ha, hb = laspy.read(a).header, laspy.read(b).header
    # A: header bounds shrunk to a quarter of the block (the points lie beyond them)
    _patch_header(a, max_x=ha.mins[0] + 30.0, max_y=ha.mins[1] + 30.0)
    # B: maxs off by 1.4e6 m (a 2,800 x 2,800 grid of 500 m tiles if the header were trusted)
    _patch_header(b, max_x=hb.maxs[0] + 1.4e6, max_y=hb.maxs[1] + 1.4e6)
    # a truncated copy of A whose name sorts between A and B, at A's place
    data = (ci_scene / a.name).read_bytes()
    (indir / "400060_4600000.laz").write_bytes(data[: len(data) // 3])
    zone = _zone("headers")
    cfg = write_zone_config(tmp / "c.yaml", {zone: {"input": str(indir)}}, tmp / "work", preprocess={"tile_size": 120})
    t0 = time.perf_counter()
    dry = snakemake_run("-n", "--cores", "2", f"results/{zone}/", f"--configfile={cfg}")
    dry_s = time.perf_counter() - t0
    proc = snakemake_run("--cores", "2", "--keep-going", f"results/{zone}/", f"--configfile={cfg}")
    yield {
        "zone": zone,
        "dry": dry,
        "dry_s": dry_s,
        "proc": proc,
        "work": tmp / "work",
        "out": REPO / "results" / zone,
        "ref": ci_reference,
    }
    shutil.rmtree(REPO / "results" / zone, ignore_errors=True)


def test_absurd_header_does_not_shape_the_job_graph(headers_run):
    dry = headers_run["dry"]
    assert dry.returncode == 0, dry.stderr[-2000:]
    # before the split only the splits and the plan are known: no tile job from the header
    assert re.search(r"^split_block\s+3$", dry.stdout, re.M)
    assert "infer_tile" not in dry.stdout and "preprocess_tile" not in dry.stdout
    plan = json.loads((headers_run["work"] / headers_run["zone"] / "plan.json").read_text())["blocks"]
    assert plan[CI_BLOCKS[1]]["tiles"] == ["0_0"]


def test_header_contradicting_points_gives_same_towers_and_a_warning(headers_run):
    out, ref = headers_run["out"], headers_run["ref"]
    for block in CI_BLOCKS:
        same_points(ref / "blocks" / f"{block}.laz", out / "blocks" / f"{block}.laz")
        fa, fb = tower_features(ref / "towers" / f"{block}.gpkg"), tower_features(out / "towers" / f"{block}.gpkg")
        assert len(fa) > 0 or block == CI_BLOCKS[1]
        assert fa.drop(columns="geometry").equals(fb.drop(columns="geometry"))
        # the block's preprocessing summary, as its QA page records it
        summary = json.loads((out / "qa" / f"{block}.json").read_text())["stats"]
        assert any(
            w.startswith("header: header bounds") and "contradict the points" in w for w in summary["warnings"]
        ), summary["warnings"]
    fa, fb = tower_features(ref / "towers.gpkg"), tower_features(out / "towers.gpkg")
    # at least the towers the zone's model found on the CI scene (recorded in its card): the
    # equality below compares towers, not two empty tables
    model = json.loads((headers_run["work"] / headers_run["zone"] / "model.json").read_text())["path"]
    found = json.loads((REPO / model / "model_card.json").read_text())["metrics"]["reference_zone"]["towers_predicted"]
    assert len(fa) >= found and fa.drop(columns="geometry").equals(fb.drop(columns="geometry"))


def test_truncated_block_between_two_good_ones_costs_only_itself(headers_run):
    proc, out = headers_run["proc"], headers_run["out"]
    assert proc.returncode != 0
    incomplete = (out / "INCOMPLETE.txt").read_text()
    assert re.search(r"400060_4600000: .*InputError: .*400060_4600000\.laz: trunc", incomplete), incomplete
    assert sorted(p.stem for p in (out / "blocks").iterdir()) == sorted(CI_BLOCKS)
    # its points never reached a tile: the good blocks' tiles and towers are the plain run's
    # (checked point for point above); no tile of it exists
    assert not (headers_run["work"] / headers_run["zone"] / "tiles" / "400060_4600000").exists()


# --------------------------------------------------------------------------- names, units, neighbours

#: Files of the ``names`` zone that must complete: relative path -> expected id pattern.
SAFE_NAMES = {
    "b c.laz": r"b_c-[0-9a-f]{8}",
    "blk{1}.laz": r"blk_1_-[0-9a-f]{8}",
    "é.laz": r"e-[0-9a-f]{8}",
    "flight1/a.laz": r"flight1__a-[0-9a-f]{8}",
    "flight1__a.laz": r"flight1__a-[0-9a-f]{8}",
}
#: Files that must fail at split: relative path -> regex of the one-line error.
REFUSED = {
    "feet.laz": r"feet\.laz: the file's CRS \(.*\(ftUS\)\) has horizontal unit 'US survey foot'",
    "degrees.laz": r"degrees\.laz: the file's CRS \(WGS 84\) has horizontal unit 'degree'",
    "height_ft.laz": r"height_ft\.laz: the file's CRS \(.*\) has vertical unit 'US survey foot'",
    "x.las": r"x\.las: x\.laz is the same block in a second file; keep one",
    "x.laz": r"x\.laz: x\.las is the same block in a second file; keep one",
}


@pytest.fixture(scope="module")
def names_run(ci_scene, random_model_factory, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("names")
    indir = tmp / "in"
    (indir / "flight1").mkdir(parents=True)
    a = ci_scene / f"{CI_BLOCKS[0]}.laz"
    x0, y0 = laspy.read(a).header.mins[:2]
    k = 0

    def place(rel, las):
        nonlocal k
        k += 1
        las.write(indir / rel)

    for rel in SAFE_NAMES:
        place(rel, _cut(a, x0, y0, 40, shift=(1000.0 * (k + 1), 0.0)))
    place("feet.laz", _with_crs(_cut(a, x0, y0, 40, shift=(1000.0 * (k + 1), 0.0)), "EPSG:2263"))
    place("degrees.laz", _with_crs(_cut(a, x0, y0, 40, shift=(1000.0 * (k + 1), 0.0)), "EPSG:4326"))
    place("height_ft.laz", _with_crs(_cut(a, x0, y0, 40, shift=(1000.0 * (k + 1), 0.0)), "EPSG:25831+6360"))
    xs = _cut(a, x0, y0, 40, shift=(1000.0 * (k + 1), 0.0))
    xs.write(indir / "x.las")
    xs.write(indir / "x.laz")
    # a block without NIR (point format 7) between two NIR blocks, 40 m apart: their buffers
    # hold its points, and it fails alone (the full model needs NIR)
    dx = 1000.0 * (k + 3)
    _cut(a, x0, y0, 40, shift=(dx, 0.0)).write(indir / "nir_west.laz")
    mid = _cut(a, x0, y0, 40, shift=(dx + 40, 0.0))
    nonir = laspy.LasData(laspy.LasHeader(point_format=7, version="1.4"))
    nonir.header.offsets, nonir.header.scales = mid.header.offsets, mid.header.scales
    nonir.header.add_crs(mid.header.parse_crs())
    for dim in (
        "x",
        "y",
        "z",
        "intensity",
        "classification",
        "return_number",
        "number_of_returns",
        "gps_time",
        "red",
        "green",
        "blue",
    ):
        setattr(nonir, dim, np.asarray(getattr(mid, dim)))
    nonir.write(indir / "nonir_mid.laz")
    _cut(a, x0, y0, 40, shift=(dx + 80, 0.0)).write(indir / "nir_east.laz")
    zone = _zone("names")
    cfg = write_zone_config(
        tmp / "c.yaml",
        {zone: {"input": str(indir)}},
        tmp / "work",
        inference={"model": str(random_model_factory("full")), "gate": 1.0},
    )
    proc = snakemake_run("--cores", "2", "--keep-going", f"results/{zone}/", f"--configfile={cfg}")
    yield {"zone": zone, "proc": proc, "work": tmp / "work", "out": REPO / "results" / zone, "in": indir}
    shutil.rmtree(REPO / "results" / zone, ignore_errors=True)


def _ids(run) -> dict[str, str]:
    manifest = json.loads((run["work"] / run["zone"] / "inputs.json").read_text())
    from towerpipe.io.inputs import block_ids

    return {rel: b for b, rel in block_ids(sorted(manifest)).items()}


@pytest.mark.parametrize("rel", sorted(SAFE_NAMES))
def test_any_file_name_becomes_a_safe_unique_block_id(names_run, rel):
    ids = _ids(names_run)
    block = ids[rel]
    assert re.fullmatch(SAFE_NAMES[rel], block), block
    out = names_run["out"]
    assert (out / "blocks" / f"{block}.laz").is_file()
    # the original path is kept in the products: the block's summary and its QA page
    qa = json.loads((out / "qa" / f"{block}.json").read_text())
    summary = qa["stats"]
    assert summary["source"]["relpath"] == rel and summary["path"].endswith(rel)
    assert f"input {markupsafe.escape(rel)} ·" in (out / "qa" / f"{block}.html").read_text()
    assert len(set(ids.values())) == len(ids)


@pytest.mark.parametrize("rel", sorted(REFUSED))
def test_unit_and_clash_refused_at_split_with_one_line(names_run, rel):
    block = _ids(names_run)[rel]
    text = _log_text(names_run["work"], names_run["zone"], block)
    assert re.search(REFUSED[rel], text), text[-2000:]
    split_log = _split_log(names_run["work"], names_run["zone"], block)
    assert re.search(REFUSED[rel], split_log), split_log  # found at split, before any compute
    incomplete = (names_run["out"] / "INCOMPLETE.txt").read_text()
    assert re.search(rf"{re.escape(block)}: .*" + REFUSED[rel], incomplete), incomplete
    assert not (names_run["out"] / "blocks" / f"{block}.laz").exists()


def test_neighbour_without_nir_costs_only_itself(names_run):
    out, work, zone = names_run["out"], names_run["work"], names_run["zone"]
    assert "nonir_mid: " in (out / "INCOMPLETE.txt").read_text()
    # the plan batches these small blocks, but the model cannot run on one of them: every block
    # then has jobs of its own after its split (a batch fails with any of its blocks), and that
    # one fails alone
    assert json.loads((work / zone / "plan.json").read_text())["batches"]
    assert not [*(work / zone).glob("batches/*/infer"), *(work / zone).glob("batches/*/products")]
    for b in ("nir_west", "nir_east"):
        assert (out / "blocks" / f"{b}.laz").is_file()
        tiles = list((work / zone / "tiles" / b).glob("*.npz"))
        from towerpipe.io.columns import read_meta

        notes = [n for t in tiles for n in read_meta(t)["buffer_notes"]]
        assert any("buffer points of block nonir_mid have no valid nir" in n for n in notes), notes
        assert all(read_meta(t)["has_nir"] for t in tiles)


# --------------------------------------------------------------------------- formats, nightly rerun

FORMATS = [
    ("1.1", 0),
    ("1.1", 1),
    ("1.3", 1),
    ("1.3", 4),
    ("1.3", 5),
    ("1.4", 0),
    ("1.4", 3),
    ("1.4", 5),
    ("1.4", 9),
    ("1.4", 10),
]


def _as_format(src: laspy.LasData, version: str, pf: int) -> laspy.LasData:
    las = laspy.LasData(laspy.LasHeader(point_format=pf, version=version))
    las.header.offsets, las.header.scales = src.header.offsets, src.header.scales
    dims = set(las.point_format.dimension_names)
    for dim in (
        "x",
        "y",
        "z",
        "intensity",
        "return_number",
        "number_of_returns",
        "gps_time",
        "red",
        "green",
        "blue",
        "nir",
    ):
        if dim in dims:
            setattr(las, dim, np.asarray(getattr(src, dim)))
    cls = np.asarray(src.classification)
    las.classification = np.where(cls > 31, 1, cls) if pf < 6 else cls
    return las


def _copc_flagged(src: laspy.LasData) -> laspy.LasData:
    """A LAS 1.4 pf 6 file with COPC's info VLR and hierarchy EVLR (read as plain LAZ)."""
    las = _as_format(src, "1.4", 6)
    las.header.vlrs.insert(0, laspy.VLR(user_id="copc", record_id=1, description="copc info", record_data=bytes(160)))
    las.header.evlrs = VLRList(
        [laspy.VLR(user_id="copc", record_id=1000, description="EPT hierarchy", record_data=bytes(32))]
    )
    return las


@pytest.fixture(scope="module")
def formats_run(ci_scene, random_model_factory, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("formats")
    indir = tmp / "in"
    indir.mkdir()
    a = ci_scene / f"{CI_BLOCKS[0]}.laz"
    x0, y0 = laspy.read(a).header.mins[:2]
    for i, (ver, pf) in enumerate(FORMATS):
        las = _as_format(_cut(a, x0, y0, 30, shift=(1000.0 * i, 0.0)), ver, pf)
        las.header.add_crs(CRS.from_epsg(25831)) if ver == "1.4" else None
        las.write(indir / f"las{ver.replace('.', '')}_pf{pf}.laz")
    _copc_flagged(_cut(a, x0, y0, 30, shift=(-1000.0, 0.0))).write(indir / "copc.copc.laz")
    zone = _zone("formats")
    cfg = write_zone_config(
        tmp / "c.yaml",
        {zone: {"input": str(indir), "crs": "EPSG:25831"}},
        tmp / "work",
        inference={"model": str(random_model_factory("geometry")), "gate": 1.0},
    )
    first = snakemake_run("--cores", "2", f"results/{zone}/", f"--configfile={cfg}")
    run = {
        "zone": zone,
        "first": first,
        "work": tmp / "work",
        "out": REPO / "results" / zone,
        "in": indir,
        "cfg": cfg,
        "tmp": tmp,
    }
    yield run
    shutil.rmtree(REPO / "results" / zone, ignore_errors=True)


@pytest.mark.parametrize("fmt", [f"las{v.replace('.', '')}_pf{pf}" for v, pf in FORMATS] + ["copc.copc"])
def test_every_las_format_is_carried_to_the_end(formats_run, fmt):
    first = formats_run["first"]
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    src = laspy.read(formats_run["in"] / f"{fmt}.laz")
    got = laspy.read(formats_run["out"] / "blocks" / f"{fmt}.laz")
    assert (got.header.version, got.point_format.id) == (src.header.version, src.point_format.id)
    size = src.points.array.dtype.itemsize
    ra, rb = src.points.array.copy(), got.points.array.copy()
    ra["classification" if src.point_format.id >= 6 else "raw_classification"] = 0
    rb["classification" if src.point_format.id >= 6 else "raw_classification"] = 0
    np.testing.assert_array_equal(
        ra.view(np.uint8).reshape(len(ra), -1), rb.view(np.uint8).reshape(len(rb), -1)[:, :size]
    )
    assert "TowerProbability" in got.point_format.dimension_names
    assert not [v for v in list(got.header.vlrs) + list(got.header.evlrs or []) if v.user_id == "copc"]


@pytest.fixture(scope="module")
def nightly_rerun(formats_run):
    """A nightly rerun after one block got other content with an older mtime and one a broken file."""
    assert formats_run["first"].returncode == 0
    indir, out, zone = formats_run["in"], formats_run["out"], formats_run["zone"]
    old = {p.name: p.read_bytes() for p in (out / "blocks").iterdir()}
    # las14_pf0: other content (half of its points), mtime a year older than the original
    changed = indir / "las14_pf0.laz"
    st = changed.stat()
    las = laspy.read(changed)
    half = laspy.LasData(las.header.copy())
    half.points = las.points[np.arange(0, len(las.points), 2)]
    half.write(changed)
    os.utime(changed, (st.st_atime - 3e7, st.st_mtime - 3e7))
    # las11_pf0: replaced by a broken file, also with an old mtime
    broken = indir / "las11_pf0.laz"
    st = broken.stat()
    broken.write_bytes(broken.read_bytes()[:2000])
    os.utime(broken, (st.st_atime - 3e7, st.st_mtime - 3e7))
    dry = snakemake_run("-n", "--cores", "2", f"results/{zone}/", f"--configfile={formats_run['cfg']}")
    # poll results/<zone>/ while the nightly command runs
    missing: list[float] = []
    stop = threading.Event()

    def poll():
        while not stop.is_set():
            if not out.is_dir():
                missing.append(time.monotonic())
            time.sleep(0.0005)

    poller = threading.Thread(target=poll)
    poller.start()
    env = dict(os.environ, SNAKEMAKE=f"{sys.executable} -m snakemake", PYTHON=sys.executable)
    try:
        proc = subprocess.run(
            ["bash", "scripts/nightly.sh", zone, str(formats_run["cfg"])],
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
        )
    finally:
        stop.set()
        poller.join()
    return {"dry": dry, "proc": proc, "missing": missing, "old": old, "half": len(half.points)}


def test_new_content_with_an_older_mtime_is_reprocessed(formats_run, nightly_rerun):
    dry = nightly_rerun["dry"].stdout
    # the two blocks' split batch (small blocks: their splits are one job)
    assert re.search(r"^split_batch\s+1$", dry, re.M), dry[-3000:]
    got = laspy.read(formats_run["out"] / "blocks" / "las14_pf0.laz")
    assert len(got.points) == nightly_rerun["half"]


def test_failed_blocks_old_products_are_not_republished(formats_run, nightly_rerun):
    out = formats_run["out"]
    assert nightly_rerun["proc"].returncode != 0
    incomplete = (out / "INCOMPLETE.txt").read_text()
    assert re.search(r"las11_pf0: .*las11_pf0\.laz", incomplete), incomplete
    assert not (out / "blocks" / "las11_pf0.laz").exists() and "las11_pf0.laz" in nightly_rerun["old"]
    assert not (out / "towers" / "las11_pf0.gpkg").exists()
    assert "las11_pf0" in (out / "qa" / "index.html").read_text()


def test_zone_directory_exists_at_every_moment_of_a_nightly_rerun(formats_run, nightly_rerun):
    assert nightly_rerun["missing"] == []
    assert _leftovers(formats_run["out"].parent, formats_run["work"]) == []


# --------------------------------------------------------------------------- every block bad


def test_all_bad_zone_publishes_incomplete_with_a_qa_index(tmp_path, ci_scene):
    indir = tmp_path / "in"
    indir.mkdir()
    (indir / "text.laz").write_text("x,y,z\n" * 100)
    data = (ci_scene / f"{CI_BLOCKS[0]}.laz").read_bytes()
    (indir / "cut.laz").write_bytes(data[: len(data) // 2])
    _with_crs(laspy.read(ci_scene / f"{CI_BLOCKS[1]}.laz"), "EPSG:2263").write(indir / "feet.laz")
    zone = _zone("allbad")
    cfg = write_zone_config(tmp_path / "c.yaml", {zone: {"input": str(indir)}}, tmp_path / "work")
    out = REPO / "results" / zone
    try:
        proc = snakemake_run("--cores", "2", "--keep-going", f"results/{zone}/", f"--configfile={cfg}")
        assert proc.returncode != 0
        assert "onerror" not in proc.stderr.lower() or "Traceback" not in proc.stderr, proc.stderr[-3000:]
        incomplete = (out / "INCOMPLETE.txt").read_text()
        index = (out / "qa" / "index.html").read_text()
        for b, why in (("text", "not a readable LAS/LAZ file"), ("cut", "trunc"), ("feet", "US survey foot")):
            assert re.search(rf"{b}: .*{why}", incomplete), incomplete
            assert b in index and why in index
        assert not (out / "towers.gpkg").exists()  # nothing to merge, no CRS
        assert _leftovers(out.parent, tmp_path / "work") == []
    finally:
        shutil.rmtree(out, ignore_errors=True)


def test_previous_runs_classified_blocks_as_input(request, tmp_path):
    """A zone of the pipeline's own classified blocks runs again: its dimensions are replaced, not
    added twice, and it finds the same towers."""
    from towerpipe.io.lasformat import PROB_DIMENSION, TOWER_ID_DIMENSION

    ci_reference = request.getfixturevalue("ci_reference")
    zone = _zone("again")
    cfg = write_zone_config(
        tmp_path / "c.yaml",
        {zone: {"input": str(ci_reference / "blocks")}},
        tmp_path / "work",
        preprocess={"tile_size": 120},
    )
    try:
        proc = snakemake_run("--cores", "2", f"results/{zone}/", f"--configfile={cfg}")
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        fa = tower_features(ci_reference / "towers.gpkg")
        fb = tower_features(REPO / "results" / zone / "towers.gpkg")
        assert len(fb) == len(fa) > 0
        for col in ("centroid_x", "centroid_y", "height_m"):
            np.testing.assert_allclose(fb[col], fa[col], atol=0.05, err_msg=col)
        for out in sorted((REPO / "results" / zone / "blocks").glob("*.laz")):
            dims = list(laspy.read(out).point_format.dimension_names)
            assert dims.count(PROB_DIMENSION) == 1 and dims.count(TOWER_ID_DIMENSION) == 1, (out.name, dims)
    finally:
        shutil.rmtree(REPO / "results" / zone, ignore_errors=True)
