"""A zone of small blocks in batches (:mod:`towerpipe.preprocess.batches`): two jobs a batch
make the products of a job per tile and per block, point for point; a block that cannot be read
still costs only itself."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import uuid
import zipfile
from collections import Counter

import pytest

from conftest import CI_BLOCKS, REPO, same_points, snakemake_run, tower_features, write_zone_config
from towerpipe.io.atomic import staging_path

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]

#: the CI blocks (about 115,000 points each) count as small: one batch of both
BATCHED = {"block_points": 1_000_000}


def stable(obj):
    """A QA record without what names the run or measures the machine (zone, times, memory)."""
    if isinstance(obj, dict):
        return {k: stable(v) for k, v in obj.items() if k not in ("zone", "timings", "peak_rss_mb", "generated_at")}
    return [stable(v) for v in obj] if isinstance(obj, list) else obj


def finished_rules(proc):
    return Counter(re.findall(r"Finished jobid: \d+ \(Rule: (\w+)\)", proc.stdout + proc.stderr))


@pytest.fixture
def batched_zone(ci_scene, tmp_path):
    """Run a zone of ``indir`` in batches (``zone``: again): ``(proc, results dir, work dir)``."""
    zones = []

    def run(indir, *args, zone=None):
        zone = zone or f"pytest_batch_{uuid.uuid4().hex[:6]}"
        zones.append(zone)
        cfg = write_zone_config(
            tmp_path / f"{zone}.yaml",
            {zone: {"input": str(indir)}},
            tmp_path / "work",
            preprocess={"tile_size": 120},
            batch=BATCHED,
        )
        proc = snakemake_run("--cores", "2", *args, f"results/{zone}/", f"--configfile={cfg}")
        return proc, REPO / "results" / zone, tmp_path / "work" / zone

    yield run
    for zone in zones:
        shutil.rmtree(REPO / "results" / zone, ignore_errors=True)


def test_a_batched_zone_equals_the_per_block_run(ci_scene, ci_reference, batched_zone):
    proc, out, work = batched_zone(ci_scene)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    # the two blocks' tiles, towers, LAZ and QA pages: one inference job and one products job
    assert finished_rules(proc) == {
        "split_batch": 1,
        "plan_zone": 1,
        "choose_model": 1,
        "infer_batch": 1,
        "products_batch": 1,
        "assemble_zone": 1,
        "zone_results": 1,
    }
    assert list(json.loads((work / "plan.json").read_text())["batches"].values()) == [list(CI_BLOCKS)]
    for block in CI_BLOCKS:
        same_points(ci_reference / "blocks" / f"{block}.laz", out / "blocks" / f"{block}.laz")
        ref, got = (json.loads((d / "qa" / f"{block}.json").read_text()) for d in (ci_reference, out))
        assert stable(got["stats"]) == stable(ref["stats"]) and got["flags"] == ref["flags"]
        # its page reports the time of each of its stages, as a block with jobs of its own
        stages = {t["stage"]: t for t in got["timings"]}
        assert {"split", "preprocess + inference", "towers"} <= set(stages)
        assert all(stages[s]["seconds"] > 0 for s in ("split", "preprocess + inference", "towers"))
    for layer in ("towers", "tower_points"):
        fa, fb = tower_features(ci_reference / "towers.gpkg", layer), tower_features(out / "towers.gpkg", layer)
        assert len(fa) > 0
        assert fa.drop(columns="geometry").equals(fb.drop(columns="geometry"))
        assert fa.geometry.geom_equals_exact(fb.geometry, 0.0).all()
    # the tools that read a zone's last run find its batches' files (towerpipe.io.workdir)
    from towerpipe.io import workdir

    assert len(workdir.zone_files(work.parent, work.name, workdir.PRED)) == len(CI_BLOCKS)
    assert len(workdir.zone_files(work.parent, work.name, workdir.CACHE)) == len(CI_BLOCKS)
    # a second run has nothing to do
    again, _, _ = batched_zone(ci_scene, "-n", zone=work.name)
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr, again.stdout[-2000:]
    # `snakemake --report` holds each block's QA page, as for blocks with jobs of their own
    report = work.parent / "report.zip"
    rep, _, _ = batched_zone(ci_scene, "--report", str(report), zone=work.name)
    assert rep.returncode == 0, rep.stdout[-2000:] + rep.stderr[-2000:]
    with zipfile.ZipFile(report) as z:
        pages = {n.rsplit("/", 1)[-1] for n in z.namelist() if "/qa/" in n}
    assert pages >= {f"{b}.html" for b in CI_BLOCKS} | {"index.html"}, pages


@pytest.mark.parametrize(
    "bad, split_alone",
    [
        ("header", True),  # not a point cloud: its header unreadable, its split a job of its own
        ("truncated", False),  # its header announces its points: its split is in the batch
    ],
)
def test_a_bad_block_of_a_batched_zone_costs_only_itself(ci_scene, tmp_path, batched_zone, bad, split_alone):
    indir = tmp_path / "in"
    indir.mkdir()
    for block in CI_BLOCKS:
        (indir / f"{block}.laz").symlink_to(ci_scene / f"{block}.laz")
    data = (ci_scene / f"{CI_BLOCKS[0]}.laz").read_bytes()
    (indir / "broken.laz").write_bytes(b"not a point cloud" * 100 if bad == "header" else data[: len(data) // 2])
    proc, out, work = batched_zone(indir, "--keep-going")
    assert proc.returncode != 0
    # the good blocks ran in their batch; the bad one, in no batch, failed at its towers job
    assert list(json.loads((work / "plan.json").read_text())["batches"].values()) == [list(CI_BLOCKS)]
    rules = finished_rules(proc)
    assert rules["split_batch"] == 1 and rules["split_block"] == (1 if split_alone else 0)
    assert rules["infer_batch"] == 1 and rules["products_batch"] == 1
    incomplete = (out / "INCOMPLETE.txt").read_text()
    assert "broken: towers_block: InputError" in incomplete, incomplete
    assert bad == "header" or "truncated" in incomplete, incomplete
    assert sorted(p.name for p in (out / "blocks").iterdir()) == sorted(f"{b}.laz" for b in CI_BLOCKS)


def test_a_batch_killed_midway_reruns_to_the_same_products(ci_scene, ci_reference, tmp_path):
    """``kill -9`` while the batch's inference has written one block's predictions of two, then
    the nightly command: the batch's directory, never moved into place, is made again."""
    zone = f"pytest_batch_kill_{uuid.uuid4().hex[:6]}"
    out = REPO / "results" / zone
    cfg = write_zone_config(
        tmp_path / "c.yaml",
        {zone: {"input": str(ci_scene)}},
        tmp_path / "work",
        preprocess={"tile_size": 120},
        batch=BATCHED,
    )
    try:
        cmd = [sys.executable, "-m", "snakemake", "--cores", "2", f"results/{zone}/", f"--configfile={cfg}"]
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, process_group=0)
        batches = tmp_path / "work" / zone / "batches"

        def midway():  # a block's predictions written in the batch's directory being built
            building = [staging_path(d / "infer") for d in batches.iterdir()] if batches.exists() else []
            return any(p for d in building for p in d.glob("pred/*/*.npz"))

        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and proc.poll() is None and not midway():
            time.sleep(0.05)
        assert proc.poll() is None, "the run finished before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        assert not out.exists()
        # nothing that looks made: the batch's directory is moved into place only when complete
        assert not list(batches.glob("*/infer"))
        env = dict(os.environ, SNAKEMAKE=f"{sys.executable} -m snakemake")
        rerun = subprocess.run(
            ["bash", "scripts/nightly.sh", zone, str(cfg)], cwd=REPO, env=env, capture_output=True, text=True
        )
        assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
        for block in CI_BLOCKS:
            same_points(ci_reference / "blocks" / f"{block}.laz", out / "blocks" / f"{block}.laz")
        fa, fb = tower_features(ci_reference / "towers.gpkg"), tower_features(out / "towers.gpkg")
        assert fa.drop(columns="geometry").equals(fb.drop(columns="geometry"))
        assert not [p for p in (tmp_path / "work").rglob("*") if ".part" in p.name]
    finally:
        shutil.rmtree(out, ignore_errors=True)
