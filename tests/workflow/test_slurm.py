"""A real cluster run: the CI scene through the SLURM profile on a single-node SLURM.

``scripts/slurm_local.sh start`` starts munged, slurmctld and slurmd on this machine
(``make test`` installs them with ``scripts/install_slurm.sh``); the zone is run with
``--profile workflow/profiles/slurm`` (snakemake-executor-plugin-slurm: every job an
``sbatch`` job) and its point data and GeoPackage features must equal a local run's.
Skipped, with the reason, only where SLURM cannot start (not root, no slurm-wlm).

The local cluster has no accounting database, so the run names no account (the
profile's ``mapping`` would need ``sacctmgr``), asks ``squeue`` for job states and
checks them every second instead of every 40 s.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import uuid

import pytest

from conftest import CI_BLOCKS, REPO, same_points, snakemake_run, tower_features, write_zone_config

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]


@pytest.fixture(scope="module")
def slurm():
    proc = subprocess.run(["bash", "scripts/slurm_local.sh", "start"], cwd=REPO, capture_output=True, text=True)
    if proc.returncode == 3:
        pytest.skip(f"SLURM cannot start here: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stderr


def test_zone_on_slurm_equals_local_run(slurm, ci_scene, ci_reference, tmp_path):
    zone = f"pytest_slurm_{uuid.uuid4().hex[:6]}"
    cfg = write_zone_config(
        tmp_path / "c.yaml", {zone: {"input": str(ci_scene)}}, tmp_path / "work", preprocess={"tile_size": 120}
    )
    out = REPO / "results" / zone
    try:
        proc = snakemake_run(
            "--profile",
            "workflow/profiles/slurm",
            f"--configfile={cfg}",
            "--default-resources",
            "slurm_partition=cpu",
            "mem_mb=2000",
            "runtime=30",
            "--slurm-status-command",
            "squeue",
            "--slurm-init-seconds-before-status-checks",
            "1",
            "--latency-wait",
            "5",
            "--",
            f"results/{zone}/",
        )
        text = proc.stdout + proc.stderr
        assert proc.returncode == 0, text[-4000:]
        # every job but the local zone_results ran as a SLURM job: per block its split, tile,
        # inference, towers, merge and QA, plus the plan and the assembly
        submitted = re.findall(r"Job \d+ has been submitted with SLURM jobid \d+ \(log: .*/rule_(\w+)/", text)
        assert len(submitted) == 6 * len(CI_BLOCKS) + 2, text[-4000:]
        assert {"split_block", "plan_zone", "infer_tile", "merge_block", "assemble_zone"} <= set(submitted)
        for block in CI_BLOCKS:
            same_points(ci_reference / "blocks" / f"{block}.laz", out / "blocks" / f"{block}.laz")
        for layer in ("towers", "tower_points"):
            fa, fb = tower_features(ci_reference / "towers.gpkg", layer), tower_features(out / "towers.gpkg", layer)
            assert len(fa) > 0
            assert fa.drop(columns="geometry").equals(fb.drop(columns="geometry"))
            assert fa.geometry.geom_equals_exact(fb.geometry, 0.0).all()
    finally:
        shutil.rmtree(out, ignore_errors=True)
