"""Benchmarks: throughput of the workflow against a plain ``pdal translate``.

Speed bars are ratios to a baseline measured in the same run, never absolute
seconds (the machines are shared and noisy)::

    python -m towerpipe.bench preprocess            # 1 km², 10 and 20 pts/m²
    python -m towerpipe.bench preprocess --block my.laz --repeat 3
    python -m towerpipe.bench e2e --repeat 3 --json e2e.json        # raw block -> zone products
    python -m towerpipe.bench blocks --json blocks.json             # 50 blocks of ~2,000 points
    python -m towerpipe.bench scale --e2e e2e.json --blocks blocks.json   # a night, on paper
    python -m towerpipe.bench plan --blocks 4000    # snakemake -n over 4,000 planned blocks
    python -m towerpipe.bench slurm --json slurm.json   # small blocks on SLURM: per rule vs grouped
    python -m towerpipe.bench infer --work work/<zone>  # a zone's tile inference, in one process

For each block it times ``pdal translate in.laz out.laz`` (LAZ → LAZ, one
process) and the Snakemake preprocessing of the same block (``--cores 2``,
fresh working directory), and prints medians, points/s, the ratio, and the
peak RSS of every job (from Snakemake's ``benchmark:`` files).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from towerpipe.io.columns import read_meta
from towerpipe.io.las import read_header

REPO = Path(__file__).resolve().parents[3]


def run_timed(
    cmd: list[str], *, cwd: Path | None = None, env: dict | None = None
) -> tuple[float, subprocess.CompletedProcess]:
    """Wall time of a command and its completed process (output captured); raises
    ``RuntimeError`` with its stderr tail on failure."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return dt, proc


def time_cmd(cmd: list[str], *, cwd: Path | None = None, env: dict | None = None) -> float:
    """Wall time of a command (:func:`run_timed`)."""
    return run_timed(cmd, cwd=cwd, env=env)[0]


def finish(args: argparse.Namespace, tmp: Path, res: Any) -> int:
    """End of a benchmark: its figures to ``--json``, its temporary directory removed unless kept."""
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    if not args.keep and not args.workdir:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


#: the block of the small-blocks benchmarks (side in m, pts/m², seed): about 2,000 points
SMALL_BLOCK = {"size": 16.0, "density": 8.0, "seed": 3}


def run_args(p: argparse.ArgumentParser) -> None:
    """The options every benchmark that runs something takes: repeats, workdir, keep, JSON."""
    p.add_argument("--repeat", type=int, default=1, help="runs per measurement; medians are reported")
    p.add_argument("--workdir", help="keep everything here (default: a temporary directory)")
    p.add_argument("--keep", action="store_true", help="keep the temporary directory")
    p.add_argument("--json", help="also write the figures to this JSON file")


def small_block_args(p: argparse.ArgumentParser) -> None:
    """The block of the small-blocks benchmarks (:data:`SMALL_BLOCK`)."""
    p.add_argument("--size", type=float, default=SMALL_BLOCK["size"], help="block side (m); 16 m ~ 2,000 points")
    p.add_argument("--density", type=float, default=SMALL_BLOCK["density"])
    p.add_argument("--seed", type=int, default=SMALL_BLOCK["seed"])


def make_block(out_dir: Path, *, size: float, density: float, seed: int, one_line: bool = False) -> Path:
    """One synthetic block of ``size`` m at ``density`` pts/m² (``one_line``: a single power line)."""
    from towerpipe.synth import generate_zone

    out_dir.mkdir(parents=True, exist_ok=True)
    extra = {"lines_per_km2": 0.0, "min_lines": 1} if one_line else {}
    generate_zone(out_dir, seed=seed, blocks=1, size=size, density=density, **extra)
    blocks = sorted(out_dir.glob("*.laz"))
    if len(blocks) != 1:
        raise RuntimeError(f"expected one block in {out_dir}, found {len(blocks)}")
    return blocks[0]


def pdal_translate(block: Path, tmp: Path) -> float:
    out = tmp / "translate_out.laz"
    dt = time_cmd(["pdal", "translate", str(block), str(out)])
    out.unlink(missing_ok=True)
    return dt


def _number(value: str | None) -> float:
    """A benchmark TSV cell as a float (``NA`` or empty: 0)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return 0.0


def read_benchmarks(work: Path) -> list[dict]:
    """Rows of every Snakemake benchmark TSV under ``work`` (rule, job, s, max_rss, I/O in MB, CPU s)."""
    rows = []
    for tsv in sorted(work.rglob("benchmarks/**/*.tsv")):
        with open(tsv) as fh:
            for r in csv.DictReader(fh, delimiter="\t"):
                rel = tsv.relative_to(work).parts
                rows.append(
                    {
                        "rule": rel[2] if len(rel) > 3 else rel[-1].removesuffix(".tsv"),
                        "job": "/".join(rel[3:]).removesuffix(".tsv"),
                        "s": float(r["s"]),
                        "max_rss_mb": float(r["max_rss"]),
                        "io_mb": _number(r.get("io_in")) + _number(r.get("io_out")),
                        "cpu_s": _number(r.get("cpu_time")),
                    }
                )
    return rows


def run_workflow(
    block: Path, tmp: Path, *, zone: str, target: str, cores: int = 2, extra_config: dict | None = None
) -> tuple[float, list[dict]]:
    """Run Snakemake on a one-block zone in a fresh working directory."""
    indir = tmp / f"in_{zone}"
    shutil.rmtree(indir, ignore_errors=True)
    indir.mkdir(parents=True)
    os.link(block, indir / block.name) if block.stat().st_dev == indir.stat().st_dev else shutil.copy(block, indir)
    return run_zone(
        indir, tmp, zone=zone, target=target.replace("{block}", block.stem), cores=cores, extra_config=extra_config
    )


def run_zone(
    indir: Path, tmp: Path, *, zone: str, target: str, cores: int = 2, extra_config: dict | None = None
) -> tuple[float, list[dict]]:
    """Run Snakemake on the zone of the blocks in ``indir`` in a fresh working directory."""
    work = tmp / f"work_{zone}"
    shutil.rmtree(work, ignore_errors=True)
    # a zone published there before (another run of the same name) would lend its towers' ids
    # (the registry's fallback) and its published files
    shutil.rmtree(REPO / "results" / zone, ignore_errors=True)
    cfg = {"zones": {zone: {"input": str(indir)}}, "workdir": str(work)}
    cfg.update(extra_config or {})
    cfg_file = tmp / f"{zone}.yaml"
    cfg_file.write_text(yaml.safe_dump(cfg))
    tgt = target.format(work=work, zone=zone)
    dt = time_cmd(
        [
            sys.executable,
            "-m",
            "snakemake",
            "--cores",
            str(cores),
            "--quiet",
            "all",
            f"--configfile={cfg_file}",
            "--",
            tgt,
        ],
        cwd=REPO,
    )
    return dt, read_benchmarks(work)


def bench_preprocess(args: argparse.Namespace) -> int:
    tmp = Path(args.workdir or tempfile.mkdtemp(prefix="towerpipe-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    blocks: list[tuple[str, Path]] = []
    if args.block:
        blocks = [(Path(b).stem, Path(b)) for b in args.block]
    else:
        for scale in args.scales:
            blocks.append(
                (
                    f"{scale:g}x",
                    make_block(tmp / f"block_{scale:g}x", size=args.size, density=args.density * scale, seed=args.seed),
                )
            )
    results = []
    for label, block in blocks:
        n = read_header(block).point_count
        tr, wf, rss = [], [], []
        for r in range(args.repeat):
            tr.append(pdal_translate(block, tmp))
            # a zone the verifier trains on is only prepared (split, plan, preprocess_tile); a zone
            # with products preprocesses its tiles in its inference jobs
            zone = f"bench{r}"
            dt, rows = run_workflow(
                block,
                tmp,
                zone=zone,
                target="{work}/{zone}/prepared.done",
                extra_config={"training": {"verifier_zones": [zone]}},
            )
            wf.append(dt)
            rss.append(max(row["max_rss_mb"] for row in rows))
        res = {
            "label": label,
            "points": n,
            "translate_s": statistics.median(tr),
            "preprocess_s": statistics.median(wf),
            "peak_rss_mb_per_job": max(rss),
            "translate_runs": tr,
            "preprocess_runs": wf,
        }
        res["ratio"] = res["preprocess_s"] / res["translate_s"]
        res["mpts_per_s"] = n / res["preprocess_s"] / 1e6
        results.append(res)
        print(
            f"{label:>6}: {n / 1e6:6.2f} Mpts  pdal translate {res['translate_s']:6.1f} s  "
            f"preprocess (--cores 2) {res['preprocess_s']:6.1f} s  ratio {res['ratio']:.2f}  "
            f"{res['mpts_per_s']:.2f} Mpts/s  peak RSS/job {res['peak_rss_mb_per_job']:.0f} MiB",
            flush=True,
        )
    if len(results) >= 2:
        a, b = results[0], results[-1]
        print(
            f"scaling: {b['points'] / a['points']:.2f}x points -> {b['preprocess_s'] / a['preprocess_s']:.2f}x time "
            f"(translate {b['translate_s'] / a['translate_s']:.2f}x)"
        )
    return finish(args, tmp, results)


def stage_split(rows: list[dict]) -> dict[str, dict[str, float]]:
    """Seconds and I/O (sums over jobs) and peak RSS (max over jobs) per rule."""
    out: dict[str, dict[str, float]] = {}
    for r in rows:
        d = out.setdefault(r["rule"], {"s": 0.0, "max_rss_mb": 0.0, "jobs": 0, "io_mb": 0.0})
        d["s"] += r["s"]
        d["io_mb"] += r.get("io_mb", 0.0)
        d["max_rss_mb"] = max(d["max_rss_mb"], r["max_rss_mb"])
        d["jobs"] += 1
    return out


def gate_stats(work: Path) -> dict[str, float]:
    """Windows total / passed the gate / segmented over all prediction files under ``work``, and
    the speed of the gate and the segmenter in windows per second of one job's thread.

    A window near a tile edge is seen by both tiles that hold its points (with the same inputs and
    the same answers: :mod:`towerpipe.inference.infer`), so the sums over the tiles count it twice.
    ``windows_distinct`` and ``windows_segmented_distinct`` count each window of the block once (by
    its centre, from the files' ``window_gates``)."""
    tot = {"windows_total": 0, "windows_shape_gated": 0, "windows_passed_gate": 0, "windows_segmented": 0}
    t = {"windows_classified": 0, "gate_s": 0.0, "segment_s": 0.0}
    seen: set[tuple[float, float]] = set()
    segmented: set[tuple[float, float]] = set()
    for p in work.rglob("pred/*/*.npz"):
        meta = read_meta(p)
        for k in tot:
            tot[k] += int(meta.get(k, 0))
        timings = meta.get("timings") or {}
        t["windows_classified"] += int(meta.get("windows_classified", 0))
        t["gate_s"] += float(timings.get("sample_features", 0.0)) + float(timings.get("classify", 0.0))
        t["segment_s"] += float(timings.get("segment", 0.0))
        g = meta.get("window_gates") or {}
        for x, y, s in zip(g.get("x", []), g.get("y", []), g.get("segmented", [])):
            seen.add((x, y))
            if s:
                segmented.add((x, y))
    tot["windows_distinct"], tot["windows_segmented_distinct"] = len(seen), len(segmented)
    tot["gate_windows_per_s_per_thread"] = t["windows_classified"] / t["gate_s"] if t["gate_s"] > 0 else None
    tot["segment_windows_per_s_per_thread"] = tot["windows_segmented"] / t["segment_s"] if t["segment_s"] > 0 else None
    return tot


def bench_e2e(args: argparse.Namespace) -> int:
    tmp = Path(args.workdir or tempfile.mkdtemp(prefix="towerpipe-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    block = (
        Path(args.block)
        if args.block
        else make_block(tmp / "block_e2e", size=args.size, density=args.density, seed=args.seed, one_line=True)
    )
    n = read_header(block).point_count
    tr, wf = [], []
    rows: list[dict] = []
    for r in range(args.repeat):
        tr.append(pdal_translate(block, tmp))
        dt, rows = run_workflow(
            block,
            tmp,
            zone=f"e2e{r}",
            target="results/{zone}/",
            extra_config={"inference": {"model": args.model}} if args.model else None,
        )
        wf.append(dt)
    work = tmp / f"work_e2e{args.repeat - 1}"
    g = gate_stats(work)
    res = {
        "points": n,
        "translate_s": statistics.median(tr),
        "e2e_s": statistics.median(wf),
        "translate_runs": tr,
        "e2e_runs": wf,
        "stages": stage_split(rows),
        **g,
    }
    res["ratio"] = res["e2e_s"] / res["translate_s"]
    res["gate_skip_rate"] = 1 - g["windows_passed_gate"] / max(g["windows_total"], 1)
    res["gate_skip_rate_distinct"] = 1 - g["windows_segmented_distinct"] / max(g["windows_distinct"], 1)
    print(
        f"e2e: {n / 1e6:.2f} Mpts  pdal translate {res['translate_s']:.1f} s  raw block -> zone products "
        f"(--cores 2) {res['e2e_s']:.1f} s  ratio {res['ratio']:.2f}  {n / res['e2e_s'] / 1e6:.2f} Mpts/s"
        f"  (runs {' / '.join(f'{t:.1f}' for t in wf)} s against {' / '.join(f'{t:.1f}' for t in tr)} s)"
    )
    print(
        f"gate: {g['windows_total']} windows, {g['windows_shape_gated']} left out by the shape gate, "
        f"{g['windows_passed_gate']} passed, {g['windows_segmented']} segmented "
        f"-> {100 * res['gate_skip_rate']:.2f} % skipped (summed over the tiles)"
    )
    print(
        f"gate, each window once: {g['windows_segmented_distinct']} of the block's {g['windows_distinct']} "
        f"distinct windows segmented -> {100 * res['gate_skip_rate_distinct']:.2f} % skipped "
        f"({g['windows_total'] - g['windows_distinct']} counted again by another tile)"
    )
    speed = [(k, g[f"{k}_windows_per_s_per_thread"]) for k in ("gate", "segment")]
    print("  ".join(f"{k}: {v:.1f} windows/s per thread" for k, v in speed if v is not None))
    for rule, d in sorted(res["stages"].items(), key=lambda kv: -kv[1]["s"]):
        print(f"  {rule:<16} {d['s']:7.1f} s over {d['jobs']:3d} job(s)   peak RSS {d['max_rss_mb']:6.0f} MiB")
    for r in range(args.repeat):
        shutil.rmtree(REPO / "results" / f"e2e{r}", ignore_errors=True)
    return finish(args, tmp, res)


def bench_blocks(args: argparse.Namespace) -> int:
    """A zone of many small blocks: the fixed cost of a job, whatever its work (in batches of
    blocks, as the shipped ``batch`` section plans them, or ``--block-points 0``: a job per tile
    and per block)."""
    from towerpipe.synth import generate_zone

    tmp = Path(args.workdir or tempfile.mkdtemp(prefix="towerpipe-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    indir = tmp / "blocks_in"
    shutil.rmtree(indir, ignore_errors=True)
    truth = generate_zone(indir, seed=args.seed, blocks=args.blocks, size=args.size, density=args.density)
    n = sum(b["n_points"] for b in truth.blocks)
    walls, rows, batches = [], [], 0
    extra: dict[str, Any] = {"inference": {"model": args.model}}
    if args.block_points is not None:
        extra["batch"] = {"block_points": args.block_points}
    for r in range(args.repeat):
        dt, rows = run_zone(
            indir, tmp, zone=f"blocks{r}", target="results/{zone}/", cores=args.cores, extra_config=extra
        )
        walls.append(dt)
        plan = tmp / f"work_blocks{r}" / f"blocks{r}" / "plan.json"
        batches = len(json.loads(plan.read_text()).get("batches") or {}) if plan.exists() else 0
        shutil.rmtree(REPO / "results" / f"blocks{r}", ignore_errors=True)
    job_s = sorted(row["s"] for row in rows)
    res = {
        "blocks": args.blocks,
        "batches": batches,
        "points": n,
        "cores": args.cores,
        "wall_s": statistics.median(walls),
        "wall_runs": walls,
        "jobs": len(rows),
        "job_s_sum": sum(job_s),
        "job_s_median": statistics.median(job_s),
        "max_rss_mb": max(row["max_rss_mb"] for row in rows),
        "io_mb_per_block": sum(row["io_mb"] for row in rows) / args.blocks,
        "stages": stage_split(rows),
    }
    res["core_s_per_job"] = res["wall_s"] * args.cores / res["jobs"]
    res["scheduler_s_per_job"] = max(res["wall_s"] * args.cores - res["job_s_sum"], 0.0) / res["jobs"]
    print(
        f"blocks: {args.blocks} blocks ({batches} batches), {n:,} points, {res['jobs']} jobs in {res['wall_s']:.1f} s on --cores "
        f"{args.cores}: {res['core_s_per_job']:.2f} core-s per job (job itself: median {res['job_s_median']:.2f} s; "
        f"outside the jobs: {res['scheduler_s_per_job']:.2f} core-s per job)"
    )
    return finish(args, tmp, res)


def register(sub: argparse._SubParsersAction, prog: str | None = None) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks against a plain `pdal translate` (see towerpipe.bench)",
        **({"prog": prog} if prog else {}),
    )
    bsub = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    pp = bsub.add_parser("preprocess", help="tile + ground + HAG + noise through Snakemake vs pdal translate")
    pp.add_argument("--block", nargs="*", help="existing blocks to use instead of generated ones")
    pp.add_argument("--size", type=float, default=1000.0, help="generated block side (m)")
    pp.add_argument("--density", type=float, default=10.0, help="generated density at 1x (pts/m²)")
    pp.add_argument("--scales", type=float, nargs="+", default=[1.0, 2.0], help="point multipliers")
    pp.add_argument("--seed", type=int, default=1)
    run_args(pp)
    pp.set_defaults(func=bench_preprocess)
    pe = bsub.add_parser("e2e", help="raw block -> zone products through Snakemake vs pdal translate")
    pe.add_argument("--block", help="existing block (default: a generated 1 km² block with one power line)")
    pe.add_argument("--size", type=float, default=1000.0)
    pe.add_argument("--density", type=float, default=10.0)
    pe.add_argument("--seed", type=int, default=11)
    pe.add_argument("--model", help="inference.model for the run (default: the config's, auto)")
    run_args(pe)
    pe.set_defaults(func=bench_e2e)
    pb = bsub.add_parser("blocks", help="a zone of many small blocks: the fixed cost per job")
    pb.add_argument("--blocks", type=int, default=50)
    small_block_args(pb)
    pb.add_argument("--model", default="geometry", help="inference.model for the run")
    pb.add_argument("--cores", type=int, default=2)
    pb.add_argument(
        "--block-points",
        type=int,
        help="batch.block_points for the run (0: a job per tile and per block; default: the config's)",
    )
    run_args(pb)
    pb.set_defaults(func=bench_blocks)
    from towerpipe.bench import infer, plan, scale, slurm

    infer.register(bsub)
    scale.register(bsub)
    plan.register(bsub)
    slurm.register(bsub)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m towerpipe.bench")
    sub = parser.add_subparsers(dest="command", required=True)
    # the benchmarks hang under `bench`, as in `towerpipe bench`; their usage reads as typed here
    register(sub, prog="python -m towerpipe.bench")
    args = parser.parse_args(["bench", *(argv if argv is not None else sys.argv[1:])])
    return args.func(args)
