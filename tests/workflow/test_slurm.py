"""A real cluster run: the CI scene through the SLURM profile on a single-node SLURM.

``scripts/slurm_local.sh start`` starts munged, slurmctld and slurmd on this machine
(``make test`` installs them with ``scripts/install_slurm.sh``); the zone is run with
``--profile workflow/profiles/slurm`` (snakemake-executor-plugin-slurm: ``sbatch`` jobs,
grouped as the profile says) and its point data and GeoPackage features must equal a local
run's; a file that cannot be read must fail only its own block. Skipped, with the reason,
only where SLURM cannot start (not root, no slurm-wlm).

The local cluster has no accounting database, so the run names no account (the
profile's ``mapping`` would need ``sacctmgr``), asks ``squeue`` for job states and
checks them every second instead of every 40 s
(:data:`towerpipe.bench.slurm.LOCAL_CLUSTER_ARGS`).
"""

from __future__ import annotations

import contextlib
import re
import shutil
import subprocess
import uuid

import pytest

from conftest import CI_BLOCKS, REPO, same_points, snakemake_run, tower_features, write_zone_config
from towerpipe.bench.slurm import LOCAL_CLUSTER_ARGS

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]


@pytest.fixture(scope="module")
def slurm():
    proc = subprocess.run(["bash", "scripts/slurm_local.sh", "start"], cwd=REPO, capture_output=True, text=True)
    if proc.returncode == 3:
        pytest.skip(f"SLURM cannot start here: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stderr


@contextlib.contextmanager
def zone_on_slurm(indir, tmp_path, prefix):
    """The zone of the blocks in ``indir`` through the SLURM profile on the local cluster: yields
    Snakemake's completed process and ``results/<zone>/`` (removed afterwards)."""
    zone = f"{prefix}_{uuid.uuid4().hex[:6]}"
    cfg = write_zone_config(
        tmp_path / "c.yaml", {zone: {"input": str(indir)}}, tmp_path / "work", preprocess={"tile_size": 120}
    )
    out = REPO / "results" / zone
    try:
        yield (
            snakemake_run(
                "--profile",
                "workflow/profiles/slurm",
                f"--configfile={cfg}",
                *LOCAL_CLUSTER_ARGS,
                "--",
                f"results/{zone}/",
            ),
            out,
        )
    finally:
        shutil.rmtree(out, ignore_errors=True)


def test_zone_on_slurm_equals_local_run(slurm, ci_scene, ci_reference, tmp_path):
    with zone_on_slurm(ci_scene, tmp_path, "pytest_slurm") as (proc, out):
        text = proc.stdout + proc.stderr
        assert proc.returncode == 0, text[-4000:]
        # every job but the local zone_results ran in a SLURM job, grouped as the profile says: the
        # splits together and the tiles' preprocessing and inference together (eight to a job),
        # each block's towers, merge and QA page; the plan and the assembly alone
        submitted = re.findall(r"submitted with SLURM jobid \d+ \(log: \S*/slurm_logs/((?:rule|group)_\w+)/", text)
        assert sorted(submitted) == sorted(
            ["group_split_split_block", "group_tile_infer_tile", "rule_plan_zone", "rule_assemble_zone"]
            + ["group_block_merge_block_qa_block_towers_block"] * len(CI_BLOCKS)
        ), text[-4000:]
        for block in CI_BLOCKS:
            same_points(ci_reference / "blocks" / f"{block}.laz", out / "blocks" / f"{block}.laz")
        for layer in ("towers", "tower_points"):
            fa, fb = tower_features(ci_reference / "towers.gpkg", layer), tower_features(out / "towers.gpkg", layer)
            assert len(fa) > 0
            assert fa.drop(columns="geometry").equals(fb.drop(columns="geometry"))
            assert fa.geometry.geom_equals_exact(fb.geometry, 0.0).all()


def test_a_bad_block_on_slurm_fails_alone(slurm, ci_scene, tmp_path):
    """The profile's groups join no two blocks' failures: a file that cannot be read, split in
    the same SLURM job as the good blocks, fails only its own block."""
    indir = tmp_path / "in"
    indir.mkdir()
    for block in CI_BLOCKS:
        (indir / f"{block}.laz").symlink_to(ci_scene / f"{block}.laz")
    data = (ci_scene / f"{CI_BLOCKS[0]}.laz").read_bytes()
    (indir / "truncated.laz").write_bytes(data[: len(data) // 3])
    with zone_on_slurm(indir, tmp_path, "pytest_slurm_bad") as (proc, out):
        text = proc.stdout + proc.stderr
        assert proc.returncode != 0, text[-4000:]
        assert re.search(r"submitted with SLURM jobid \d+ \(log: \S*/group_split_split_block/", text), text[-4000:]
        incomplete = (out / "INCOMPLETE.txt").read_text()
        assert "truncated" in incomplete and not any(b in incomplete for b in CI_BLOCKS), incomplete
        for block in CI_BLOCKS:
            assert (out / "blocks" / f"{block}.laz").exists()
