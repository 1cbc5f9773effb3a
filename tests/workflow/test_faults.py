"""Faults (issue #6): a run killed with SIGKILL and rerun gives the uninterrupted run's outputs.

The CI zone's scene is generated once; the zone is run uninterrupted (reference), then
in a fresh work directory it is killed (``kill -9`` of Snakemake and every job it
started) as soon as the first tile has predictions, and rerun with ``scripts/nightly.sh``. The point data
and the GeoPackage features must equal the reference (the processing timestamps aside),
and no partial file may survive.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import uuid

import laspy
import numpy as np
import pyogrio
import pytest
import yaml

from conftest import REPO

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]

SYNTH = {"seed": 4242, "blocks": 2, "size": 120, "density": 8, "preset": "test", "edge_tower": True}


def _cmd(zone, cfg):
    return [sys.executable, "-m", "snakemake", "--cores", "2", f"results/{zone}/", f"--configfile={cfg}"]


def _config(tmp, zone, workdir, synth):
    z = {"input": f"data/{zone}"}  # a synthetic zone's input is data/<zone>
    if synth:
        z["synth"] = SYNTH
    path = tmp / f"{workdir}.yaml"
    path.write_text(
        yaml.safe_dump({"zones": {zone: z}, "workdir": str(tmp / workdir), "preprocess": {"tile_size": 120}})
    )
    return path


def _run(cmd):
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


def _features(path, layer):
    df = pyogrio.read_dataframe(path, layer=layer)
    return df.drop(columns=["processed_at", "first_seen"]).sort_values("tower_id").reset_index(drop=True)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("faults")
    zone = f"pytest_kill_{uuid.uuid4().hex[:6]}"
    out = REPO / "results" / zone
    try:
        # reference: generate the scene and run uninterrupted
        _run(_cmd(zone, _config(tmp, zone, "w_ref", synth=True)))
        ref = tmp / "ref"
        shutil.copytree(out, ref)
        shutil.rmtree(out)
        # the same blocks (no regeneration) in a fresh work directory, killed in the middle
        cfg = _config(tmp, zone, "w_kill", synth=False)
        proc = subprocess.Popen(
            _cmd(zone, cfg), cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, process_group=0
        )  # its own process group: killpg ends snakemake and its jobs
        pred = tmp / "w_kill" / zone / "pred"
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and proc.poll() is None:
            if pred.exists() and any(pred.rglob("*.npz")):
                break
            time.sleep(0.2)
        assert proc.poll() is None, "the run finished before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        killed_state = {
            "results_exists": out.exists(),
            "work_files": sorted(str(p.relative_to(tmp)) for p in (tmp / "w_kill").rglob("*") if p.is_file()),
        }
        # rerun with the documented nightly command (clears the killed run's lock)
        env = dict(os.environ, SNAKEMAKE=f"{sys.executable} -m snakemake")
        proc = subprocess.run(
            ["bash", "scripts/nightly.sh", zone, str(cfg)], cwd=REPO, env=env, capture_output=True, text=True
        )
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        yield {"ref": ref, "out": out, "killed": killed_state, "tmp": tmp, "zone": zone}
    finally:
        shutil.rmtree(out, ignore_errors=True)
        shutil.rmtree(REPO / "data" / zone, ignore_errors=True)


def test_kill_leaves_no_published_zone(runs):
    # the zone directory is only ever created complete (atomic assembly)
    assert not runs["killed"]["results_exists"]
    assert any("/pred/" in f for f in runs["killed"]["work_files"])  # it was killed mid-way


def test_rerun_after_kill_equals_uninterrupted_run(runs):
    ref, out = runs["ref"], runs["out"]
    assert sorted(p.relative_to(ref).as_posix() for p in ref.rglob("*") if p.is_file()) == sorted(
        p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()
    )
    blocks = sorted((ref / "blocks").glob("*.laz"))
    assert len(blocks) == 2
    towers_total = 0
    for b in blocks:
        a, c = laspy.read(b), laspy.read(out / "blocks" / b.name)
        assert a.header.point_count == c.header.point_count
        for dim in a.point_format.dimension_names:
            np.testing.assert_array_equal(np.asarray(a[dim]), np.asarray(c[dim]), err_msg=f"{b.name}: {dim}")
        towers_total += int(np.count_nonzero(np.asarray(a.classification) == 15))
    assert towers_total > 0, "the comparison must cover predicted tower points"
    for layer in ("towers", "tower_points"):
        fa, fc = _features(ref / "towers.gpkg", layer), _features(out / "towers.gpkg", layer)
        assert len(fa) > 0
        assert fa.drop(columns="geometry").equals(fc.drop(columns="geometry"))
        assert fa.geometry.geom_equals_exact(fc.geometry, 0.0).all()


def test_no_partial_file_survives(runs):
    tmp = runs["tmp"]
    left = [p for root in (tmp / "w_kill", runs["out"]) for p in root.rglob("*") if ".part" in p.name]
    assert left == []
