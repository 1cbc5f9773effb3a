"""Execution profiles (issue #6): the default and the SLURM profile plan the same jobs.

Dry runs only (no cluster here): the SLURM profile must load its executor plugin, map
every job's resources onto SLURM (partition, account, memory, runtime) and plan the
same jobs as a local run.
"""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from conftest import REPO

pytestmark = [pytest.mark.usefixtures("pdal_cli")]


def _dry(tmp_path, *extra):
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "-n",
        *extra,
        "--configfile=.test/config/config.yaml",
        "--config",
        f"workdir={tmp_path / 'work'}",
        "--",
        "results/ci/",
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout + proc.stderr


def _jobs(text):
    return dict((m[0], int(m[1])) for m in re.findall(r"^(\w+)\s+(\d+)$", text.split("Job stats:")[1], re.M))


def test_slurm_profile_dry_run(tmp_path):
    local = _dry(tmp_path, "--cores", "2")
    slurm = _dry(tmp_path, "--profile", "workflow/profiles/slurm")
    # the cluster profile, and the workflow profile Snakemake adds to every run
    assert re.search(
        r"Using profiles? workflow/profiles/slurm and workflow specific profile workflow/profiles/default", slurm
    )
    assert _jobs(slurm) == _jobs(local) and _jobs(slurm)["total"] > 0
    resources = re.findall(r"^\s+resources: (.*)$", slurm, re.M)
    assert resources and all("slurm_partition=cpu" in r and "slurm_account=mapping" in r for r in resources)
    assert all(re.search(r"\bmem_mb=\d+", r) and re.search(r"\bruntime=\d+", r) for r in resources)
