"""A night on paper (``python -m towerpipe.bench scale``): what an area costs on 2 cores and on a
SLURM partition, projected from measured benchmarks (``bench e2e``, ``bench blocks`` and, for the
cluster's own cost of a job, ``bench slurm``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from towerpipe.bench.slurm import SLURM_PROFILE


def profile_packs(profile: Path = SLURM_PROFILE) -> dict[str, int] | None:
    """How many splits and how many tiles the profile folder ``profile`` puts in one SLURM job
    (``group-components`` of the groups of ``split_block`` and ``infer_tile``), ``None``
    when it does not group jobs."""
    cfg = yaml.safe_load((Path(profile) / "config.yaml").read_text())
    groups, components = cfg.get("groups") or {}, cfg.get("group-components") or {}
    if not groups:
        return None
    return {
        k: int(components.get(groups.get(rule), 1)) for k, rule in (("split", "split_block"), ("tile", "infer_tile"))
    }


def project(
    e2e: dict,
    blocks: dict,
    *,
    area_km2: float,
    block_m: float,
    nodes: int,
    node_cores: int,
    max_jobs: int,
    submit_per_s: float,
    e2e_km2: float = 1.0,
    slurm_start_s: float = 0.0,
    packs: dict[str, int] | None = None,
    batched: bool = False,
) -> dict:
    """What ``area_km2`` costs as blocks of ``block_m`` m, from an e2e and a small-blocks benchmark.

    The work of the jobs scales with the points (the area, at the e2e block's density); each job
    also pays the start-up of a small job (the small-blocks benchmark's median job) and, on one
    machine, the time Snakemake spends between jobs. On SLURM, each SLURM job also pays
    ``slurm_start_s`` on its node (the Snakemake that runs it there: ``bench slurm``), concurrency
    is the smaller of the partition's cores and the profile's ``jobs``, and Snakemake submits
    ``submit_per_s`` jobs a second at most. With ``packs`` (the cluster profile's groups,
    :func:`profile_packs`) a SLURM job holds ``packs["split"]`` splits, ``packs["tile"]`` tiles'
    preprocessing and inference, or one block's towers, merge and QA page; without, one rule's job.
    ``batched``: the blocks run in batches (:mod:`towerpipe.preprocess.batches`), as ``blocks``
    measured them; the profile then groups only their splits.
    """
    e2e_jobs = sum(d["jobs"] for d in e2e["stages"].values())
    e2e_s = sum(d["s"] for d in e2e["stages"].values())
    start_s = blocks["job_s_median"]
    work_per_km2 = max(e2e_s - e2e_jobs * start_s, 0.0) / e2e_km2
    share = block_m * block_m / 1e6 / e2e_km2  # of the e2e block's points in one block
    n_blocks = area_km2 * 1e6 / (block_m * block_m)
    # a block smaller than the e2e block has the small blocks' jobs; a larger one, the e2e block's per km²
    jobs = n_blocks * (blocks["jobs"] / blocks["blocks"] if share < 1 else e2e_jobs * share)
    tiles = max(1.0, e2e["stages"].get("infer_tile", {}).get("jobs", 1) * share)  # a block's tiles
    if packs is None:
        slurm_jobs = jobs
    elif batched:  # the splits grouped; a batch's two jobs are already many blocks'
        slurm_jobs = n_blocks / packs["split"] + max(jobs - n_blocks, 0.0)
    else:
        slurm_jobs = n_blocks * (1.0 / packs["split"] + tiles / packs["tile"] + 1.0)
    # memory: a tile job holds at most one tile (<= preprocess.tile_size) and its buffer, so the e2e
    # block's peak bounds smaller blocks; I/O follows the points
    rss = max(d["max_rss_mb"] for d in e2e["stages"].values())
    io = sum(d.get("io_mb", 0.0) for d in e2e["stages"].values()) * share
    job_core_s = area_km2 * work_per_km2 + jobs * start_s
    local_core_s = job_core_s + jobs * blocks["scheduler_s_per_job"]
    slurm_core_s = job_core_s + slurm_jobs * slurm_start_s
    concurrency = min(nodes * node_cores, max_jobs)
    return {
        "area_km2": area_km2,
        "block_m": block_m,
        "batched": batched,
        "blocks": n_blocks,
        "jobs": jobs,
        "core_h": job_core_s / 3600,
        "wall_h_2_cores": local_core_s / 2 / 3600,
        "slurm_jobs": slurm_jobs,
        "slurm_core_h": slurm_core_s / 3600,
        "wall_h_slurm": max(slurm_core_s / concurrency, slurm_jobs / submit_per_s) / 3600,
        "slurm_bound": "submission" if slurm_jobs / submit_per_s > slurm_core_s / concurrency else "cores",
        "peak_rss_mb_per_job": rss,
        "io_mb_per_block": io,
    }


def bench_scale(args: argparse.Namespace) -> int:
    """Project a night's area from measured benchmarks (``bench e2e --json``, ``bench blocks --json``,
    optionally ``bench slurm --json``), on SLURM with a job per rule and with the profile's groups."""
    from towerpipe.config import effective_config

    e2e = json.loads(Path(args.e2e).read_text())
    blocks = json.loads(Path(args.blocks).read_text())
    # blocks of more points than batch.block_points have jobs of their own: measured by a
    # small-blocks run with --block-points 0 when given
    per_block = json.loads(Path(args.blocks_per_block).read_text()) if args.blocks_per_block else blocks
    block_points = effective_config()["batch"]["block_points"]
    slurm = json.loads(Path(args.slurm).read_text()) if args.slurm else None
    start = {k: slurm[k]["node_start_s"] if slurm else 0.0 for k in ("per_rule", "grouped")}
    rows = []
    for b in args.block_m:
        batched = bool(blocks.get("batches")) and e2e["points"] * b * b / 1e6 / args.e2e_km2 <= block_points
        small = blocks if batched else per_block
        common = dict(
            area_km2=args.area,
            block_m=b,
            nodes=args.nodes,
            node_cores=args.node_cores,
            max_jobs=args.max_jobs,
            submit_per_s=args.submit_per_s,
            e2e_km2=args.e2e_km2,
        )
        per_rule = project(e2e, small, **common, slurm_start_s=start["per_rule"], batched=batched)
        grouped = project(e2e, small, **common, slurm_start_s=start["grouped"], packs=profile_packs(), batched=batched)
        rows.append(
            {
                **per_rule,
                "grouped": {k: grouped[k] for k in ("slurm_jobs", "slurm_core_h", "wall_h_slurm", "slurm_bound")},
            }
        )
    print(
        f"| {args.area:,.0f} km² as blocks of | blocks | jobs | core-hours | wall on 2 cores | on {args.nodes} × "
        f"{args.node_cores} cores, a SLURM job per rule | grouped (the profile) | peak RSS per job | I/O per block |"
    )
    print("|---|---|---|---|---|---|---|---|---|")

    def cluster(r: dict) -> str:
        return (
            f"{r['slurm_jobs']:,.0f} jobs, {r['slurm_core_h']:,.0f} core-h, {r['wall_h_slurm']:,.2f} h "
            f"({r['slurm_bound']}-bound)"
        )

    for r in rows:
        print(
            f"| {r['block_m']:.0f} m{' (batches)' if r['batched'] else ''} | {r['blocks']:,.0f} | {r['jobs']:,.0f} | "
            f"{r['core_h']:,.0f} | "
            f"{r['wall_h_2_cores']:,.1f} h | {cluster(r)} | {cluster(r['grouped'])} | "
            f"≤ {r['peak_rss_mb_per_job']:,.0f} MiB | {r['io_mb_per_block']:,.0f} MB |"
        )
    if not args.slurm:
        print("(no --slurm: a SLURM job's start on its node counted as 0 s)")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def register(bsub: argparse._SubParsersAction) -> None:
    ps = bsub.add_parser("scale", help="project a night's area from the e2e and blocks benchmarks' JSON")
    ps.add_argument("--e2e", required=True, help="JSON of `bench e2e --json`")
    ps.add_argument("--e2e-km2", type=float, default=1.0, help="area of the e2e block (km²)")
    ps.add_argument("--blocks", required=True, help="JSON of `bench blocks --json`")
    ps.add_argument(
        "--blocks-per-block",
        help="JSON of `bench blocks --block-points 0 --json` (jobs of blocks too large for batches; default: --blocks)",
    )
    ps.add_argument("--slurm", help="JSON of `bench slurm --json` (a SLURM job's start on its node)")
    ps.add_argument("--area", type=float, default=1000.0, help="km² a night")
    ps.add_argument("--block-m", type=float, nargs="+", default=[1000.0, 500.0, 250.0, 50.0], help="block sides (m)")
    ps.add_argument("--nodes", type=int, default=20)
    ps.add_argument("--node-cores", type=int, default=32)
    ps.add_argument("--max-jobs", type=int, default=200, help="the SLURM profile's `jobs`")
    ps.add_argument("--submit-per-s", type=float, default=10.0, help="jobs Snakemake submits per second")
    ps.add_argument("--json")
    ps.set_defaults(func=bench_scale)
