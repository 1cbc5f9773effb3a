"""Benchmark: planning a zone of many small blocks (``python -m towerpipe.bench plan``).

What a nightly run of thousands of delivered tiles pays before any job runs: ``snakemake
-n`` over a zone whose blocks are all split and planned, so the dry run lists every job.
The zone is ``--blocks`` copies of one small generated block on a grid; the workflow splits
them (in batches, rule ``split_batch``) and makes the plan and the model choice with its own
checkpoints, then the dry run is timed ``--repeat`` times (median). The baseline
in the same run is the dry run of a zone of ``--blocks / 10`` blocks: planning should grow
no faster than the jobs.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

from towerpipe.bench import REPO, finish, make_block, run_args, run_timed, small_block_args, time_cmd


def copy_block(block: Path, out_dir: Path, n: int, size: float) -> list[Path]:
    """``n`` copies of ``block`` on a grid of ``size`` m, named by their corner as agencies name tiles."""
    import laspy

    las = laspy.read(block)
    x, y = np.array(las.x), np.array(las.y)
    x0, y0 = float(las.header.mins[0]), float(las.header.mins[1])
    side = int(np.ceil(np.sqrt(n)))
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(n):
        dx, dy = (k % side) * size, (k // side) * size
        las.x, las.y = x + dx, y + dy
        path = out_dir / f"{x0 + dx:.0f}_{y0 + dy:.0f}.laz"
        las.write(path)
        paths.append(path)
    return paths


def planned_zone(tmp: Path, block: Path, n: int, size: float, zone: str) -> tuple[Path, int]:
    """A zone of ``n`` copies of ``block``, split and planned (kept from an earlier run in the
    same ``--workdir``); its config file and number of blocks."""
    import yaml

    indir, work, cfg = tmp / f"in_{zone}", tmp / f"work_{zone}", tmp / f"{zone}.yaml"
    plan, choice = work / zone / "plan.json", work / zone / "model.json"
    if not (cfg.is_file() and plan.is_file()):
        shutil.rmtree(indir, ignore_errors=True)
        shutil.rmtree(work, ignore_errors=True)
        copy_block(block, indir, n, size)
        cfg.write_text(yaml.safe_dump({"zones": {zone: {"input": str(indir)}}, "workdir": str(work)}))
    if not choice.is_file():  # both checkpoints made (the plan, the model choice): the dry run lists every job
        smk = [sys.executable, "-m", "snakemake", "--cores", "2", "--quiet", "all", f"--configfile={cfg}", "--"]
        time_cmd([*smk, str(plan), str(choice)], cwd=REPO)
    return cfg, len(json.loads(plan.read_text())["blocks"])


def dry_run(cfg: Path, zone: str) -> tuple[float, int]:
    """Wall time of ``snakemake -n results/<zone>/`` and the number of jobs it lists."""
    cmd = [sys.executable, "-m", "snakemake", "-n", "--cores", "2", f"results/{zone}/", f"--configfile={cfg}"]
    dt, proc = run_timed(cmd, cwd=REPO)
    totals = [int(line.split()[-1]) for line in proc.stdout.splitlines() if line.startswith("total ")]
    return dt, max(totals, default=0)


def bench_plan(args: argparse.Namespace) -> int:
    tmp = Path(args.workdir or tempfile.mkdtemp(prefix="towerpipe-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    block = next((tmp / "block_plan").glob("*.laz"), None) or make_block(
        tmp / "block_plan", size=args.size, density=args.density, seed=args.seed
    )
    res = {}
    for label, n in (("baseline", max(args.blocks // 10, 1)), ("zone", args.blocks)):
        cfg, planned = planned_zone(tmp, block, n, args.size, f"plan{n}")
        runs = [dry_run(cfg, f"plan{n}") for _ in range(args.repeat)]
        walls = [dt for dt, _ in runs]
        res[label] = {"blocks": planned, "jobs": runs[-1][1], "dry_run_s": statistics.median(walls), "runs": walls}
        print(
            f"plan: {planned} blocks, {runs[-1][1]:,} jobs: snakemake -n {res[label]['dry_run_s']:.1f} s "
            f"({1e3 * res[label]['dry_run_s'] / max(runs[-1][1], 1):.2f} ms a job)"
        )
    res["ratio"] = res["zone"]["dry_run_s"] / res["baseline"]["dry_run_s"]
    res["jobs_ratio"] = res["zone"]["jobs"] / max(res["baseline"]["jobs"], 1)
    print(f"plan: {res['jobs_ratio']:.1f} × the jobs -> {res['ratio']:.1f} × the time of the dry run")
    return finish(args, tmp, res)


def register(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("plan", help="snakemake -n over a zone of many small blocks, split and planned")
    p.add_argument("--blocks", type=int, default=4000)
    small_block_args(p)
    run_args(p)
    p.set_defaults(func=bench_plan)
