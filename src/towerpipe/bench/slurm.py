"""Benchmark: a zone of small blocks on SLURM, a job per rule against the profile's groups
(``python -m towerpipe.bench slurm``).

Every SLURM job starts a Snakemake of its own on its node before its rule's script runs, so on
a cluster a job costs that start on top of its work. The benchmark runs one zone of
``--blocks`` small generated blocks twice through ``workflow/profiles/slurm`` on the
single-node cluster of ``scripts/slurm_local.sh``: first with the profile's ``groups`` and
``group-components`` removed (the baseline: one SLURM job per rule and wildcard), then as the
profile stands. For each run it reports the wall time, the SLURM jobs submitted, the
core-seconds SLURM allocated to them (run time × CPUs, read from ``scontrol show job`` while
the run goes) and what a SLURM job spends on its node besides its rules' scripts (the
Snakemake that runs it there): the SLURM jobs' run time less their rules' own (Snakemake's
``benchmark:`` files), per SLURM job. ``bench scale --slurm`` projects a night on a cluster
from this JSON.

The local cluster is one node with this machine's cores: the wall times say little about a
partition of many nodes (and SLURM's status checks back off while nothing finishes); the
jobs submitted and the core-seconds they hold are what carries over.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import yaml

from towerpipe.bench import REPO, finish, read_benchmarks, run_args, small_block_args

#: The cluster profile the benchmark runs (and ``bench scale`` reads its groups from).
SLURM_PROFILE = REPO / "workflow" / "profiles" / "slurm"

#: The profile's keys that group jobs (removed for the baseline run).
GROUP_KEYS = ("groups", "group-components")

#: Settings of the local single-node cluster (no accounting database: no account; job states
#: from ``squeue``, checked every second), as ``tests/workflow/test_slurm.py`` runs it.
LOCAL_CLUSTER_ARGS = (
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
)


def _seconds(value: str) -> int:
    """SLURM's ``[days-]hh:mm:ss`` as seconds."""
    days, _, hms = value.rpartition("-")
    h, m, s = (int(v) for v in hms.split(":"))
    return int(days or 0) * 86400 + h * 3600 + m * 60 + s


def slurm_jobs() -> dict[int, dict[str, Any]]:
    """The jobs ``scontrol`` still knows (completed ones for ``MinJobAge`` seconds)."""
    out = subprocess.run(["scontrol", "show", "job", "-o"], capture_output=True, text=True).stdout
    jobs = {}
    for line in out.splitlines():
        f = dict(re.findall(r"(\w+)=(\S*)", line))
        if "JobId" in f:
            jobs[int(f["JobId"])] = {
                "run_s": _seconds(f.get("RunTime", "0:0:0")),
                "cpus": int(f.get("NumCPUs", "1") or 1),
            }
    return jobs


class JobWatch:
    """Collects the SLURM jobs started after it was made, every few seconds, until stopped
    (``scontrol`` forgets a finished job after ``MinJobAge``: a long run would lose its first ones)."""

    def __init__(self, every_s: float = 5.0) -> None:
        self.first = max(slurm_jobs(), default=0) + 1
        self.jobs: dict[int, dict[str, Any]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, args=(every_s,), daemon=True)
        self._thread.start()

    def _loop(self, every_s: float) -> None:
        while not self._stop.wait(every_s):
            self._collect()

    def _collect(self) -> None:
        self.jobs.update({k: v for k, v in slurm_jobs().items() if k >= self.first})

    def stop(self) -> dict[int, dict[str, Any]]:
        self._stop.set()
        self._thread.join()
        self._collect()
        return self.jobs


def profile_without_groups(dst: Path) -> Path:
    """A copy of ``workflow/profiles/slurm`` without :data:`GROUP_KEYS`: one SLURM job per rule."""
    shutil.copytree(SLURM_PROFILE, dst, dirs_exist_ok=True)
    cfg = yaml.safe_load((SLURM_PROFILE / "config.yaml").read_text())
    (dst / "config.yaml").write_text(yaml.safe_dump({k: v for k, v in cfg.items() if k not in GROUP_KEYS}))
    return dst


def run_on_slurm(indir: Path, tmp: Path, zone: str, profile: Path) -> dict[str, Any]:
    """One zone through ``profile`` on the local cluster: wall, SLURM jobs, their core-seconds."""
    work = tmp / f"work_{zone}"
    shutil.rmtree(work, ignore_errors=True)
    cfg = tmp / f"{zone}.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "zones": {zone: {"input": str(indir)}},
                "workdir": str(work),
                "inference": {"model": "geometry"},
                # what it measures is the profile's grouping of the per-block jobs: no batches
                "batch": {"block_points": 0},
            }
        )
    )
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "--profile",
        str(profile),
        f"--configfile={cfg}",
        *LOCAL_CLUSTER_ARGS,
        "--",
        f"results/{zone}/",
    ]
    watch = JobWatch()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    jobs = watch.stop()
    shutil.rmtree(REPO / "results" / zone, ignore_errors=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {(proc.stdout + proc.stderr)[-3000:]}")
    rows = read_benchmarks(work)
    submitted = re.findall(r"submitted with SLURM jobid (\d+)", proc.stdout + proc.stderr)
    run_s, rule_s = sum(j["run_s"] for j in jobs.values()), sum(r["s"] for r in rows)
    return {
        "wall_s": wall,
        "slurm_jobs": len(submitted),
        "rule_jobs": len(rows),
        "slurm_core_s": sum(j["run_s"] * j["cpus"] for j in jobs.values()),
        "slurm_run_s": run_s,
        "jobs_seen": len(jobs),
        "rule_s": rule_s,
        # what a SLURM job spends on its node besides its rules' scripts (its Snakemake)
        "node_start_s": (run_s - rule_s) / max(len(jobs), 1),
    }


def bench_slurm(args: argparse.Namespace) -> int:
    from towerpipe.synth import generate_zone

    proc = subprocess.run(["bash", "scripts/slurm_local.sh", "start"], cwd=REPO, capture_output=True, text=True)
    if proc.returncode != 0:
        print(f"slurm: no local cluster: {proc.stderr.strip()}", file=sys.stderr)
        return 3
    tmp = Path(args.workdir or tempfile.mkdtemp(prefix="towerpipe-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    indir = tmp / "blocks_in"
    shutil.rmtree(indir, ignore_errors=True)
    generate_zone(indir, seed=args.seed, blocks=args.blocks, size=args.size, density=args.density)
    runs = {
        "per_rule": run_on_slurm(indir, tmp, "slurm_rules", profile_without_groups(tmp / "profile_rules")),
        "grouped": run_on_slurm(indir, tmp, "slurm_groups", SLURM_PROFILE),
    }
    base = runs["per_rule"]
    res: dict[str, Any] = {"blocks": args.blocks, **runs}
    res["jobs_ratio"] = runs["grouped"]["slurm_jobs"] / max(base["slurm_jobs"], 1)
    res["core_s_ratio"] = runs["grouped"]["slurm_core_s"] / max(base["slurm_core_s"], 1)
    res["wall_ratio"] = runs["grouped"]["wall_s"] / base["wall_s"]
    for label, r in runs.items():
        print(
            f"slurm ({label}): {args.blocks} blocks, {r['rule_jobs']} rule jobs in {r['slurm_jobs']} SLURM jobs, "
            f"{r['slurm_core_s']:,.0f} core-s allocated (the rules themselves: {r['rule_s']:,.0f} s), "
            f"wall {r['wall_s']:.0f} s; a SLURM job's own start on its node: {r['node_start_s']:.1f} s"
        )
    print(
        f"slurm: grouped / per rule: {res['jobs_ratio']:.2f} × the SLURM jobs, {res['core_s_ratio']:.2f} × the "
        f"core-s allocated, {res['wall_ratio']:.2f} × the wall (one node)"
    )
    return finish(args, tmp, res)


def register(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("slurm", help="small blocks on the local SLURM cluster: a job per rule vs grouped")
    p.add_argument("--blocks", type=int, default=8)
    small_block_args(p)
    run_args(p)
    p.set_defaults(func=bench_slurm)
