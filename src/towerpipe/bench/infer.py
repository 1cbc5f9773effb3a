"""Benchmark: the inference half of a zone's tile jobs, in one process (``python -m towerpipe.bench infer``).

For comparing two versions of the inference on the same tiles without Snakemake, PDAL or the
jobs' starts: after a run of a zone (``snakemake --cores 2 results/<zone>/``, or ``bench e2e
--keep``), each of its tiles is read and given what its ``infer_tile`` job gives it after the
preprocessing (:func:`towerpipe.jobs.steps.infer_step`: the tile's conductor points, then the
candidate windows, the shape gate, the classifier and the segmenter with the zone's model choice,
the config's verifier and ``inference`` settings), writing to a temporary directory. The
baseline in the same run is reading the tiles. Run it from two checkouts, alternating, to
compare them::

    python -m towerpipe.bench infer --work work/e2e0/e2e0 --repeat 3
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from towerpipe.bench import finish, run_args


def bench_infer(args: argparse.Namespace) -> int:
    from towerpipe.config import InferenceConfig, effective_config
    from towerpipe.io import workdir
    from towerpipe.io.columns import read_meta
    from towerpipe.io.tiles import load_tile
    from towerpipe.jobs.steps import infer_step

    work = Path(args.work)
    tiles = workdir.zone_files(work.parent, work.name, workdir.TILE)
    if not tiles:
        raise SystemExit(f"bench infer: no tiles under {work}: run the zone first")
    cfg = effective_config()
    settings = InferenceConfig.from_config(cfg)
    tmp = Path(args.workdir or tempfile.mkdtemp(prefix="towerpipe-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    read_s, infer_s, windows = [], [], 0
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        loaded = [load_tile(p) for p in tiles]
        read_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for p, tile in zip(tiles, loaded, strict=True):
            infer_step(
                p,
                None,
                tmp / "pred.npz",
                settings,
                out_wires=tmp / "wires.npz",
                tile=tile,
                choice=work / "model.json",
                verifier=cfg["towers"]["verifier"],
            )
            if len(infer_s) == 0:
                windows += int(read_meta(tmp / "pred.npz").get("windows_total", 0))
        infer_s.append(time.perf_counter() - t0)
    res = {
        "tiles": len(tiles),
        "windows": windows,
        "read_s": statistics.median(read_s),
        "infer_s": statistics.median(infer_s),
        "infer_runs": infer_s,
    }
    res["ratio"] = res["infer_s"] / max(res["read_s"], 1e-9)
    print(
        f"infer: {len(tiles)} tiles, {windows:,} candidate windows: reading them {res['read_s']:.2f} s, "
        f"their inference {res['infer_s']:.2f} s ({res['infer_s'] / len(tiles):.2f} s a tile; "
        f"runs {', '.join(f'{t:.2f}' for t in infer_s)}), {res['ratio']:.1f} × the read"
    )
    return finish(args, tmp, res)


def register(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("infer", help="the inference half of a zone's tile jobs, in one process")
    p.add_argument("--work", required=True, help="the zone's working directory (work/<zone>) after a run")
    run_args(p)
    p.set_defaults(func=bench_infer)
