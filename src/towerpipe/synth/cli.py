"""Sub-commands ``towerpipe synth`` and ``towerpipe synth-report``."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def _synth(args: argparse.Namespace) -> int:
    from towerpipe.synth.zone import generate_zone

    truth = generate_zone(
        args.out,
        seed=args.seed,
        blocks=args.blocks,
        size=args.size,
        density=args.density,
        crs=args.crs,
        origin=(args.x0, args.y0),
        preset=args.preset,
        edge_tower=args.edge_tower,
        tower_source=args.tower_source,
        real_towers=args.real_towers,
        real_backgrounds=args.real_backgrounds,
        parallel=args.parallel,
    )
    n = sum(b["n_points"] for b in truth.blocks)
    print(f"wrote {len(truth.blocks)} blocks ({n} points) and {len(truth.towers)} towers to {truth.out_dir}")
    return 0


def _report(args: argparse.Namespace) -> int:
    from towerpipe.synth.report import realism_report

    path = realism_report(args.zone, args.out, real_towers=args.real_towers, density=args.density)
    print(f"wrote {path}")
    return 0


def register(subparsers) -> None:
    """Add ``synth`` and ``synth-report`` to the ``towerpipe`` command line."""
    p = subparsers.add_parser("synth", help="generate a synthetic airborne zone (LAZ blocks + tower truth)")
    p.add_argument("--seed", type=int, required=True, help="random seed (same seed, same files)")
    p.add_argument("--blocks", type=int, default=4, help="number of adjoining square blocks")
    p.add_argument("--size", type=float, default=250.0, help="block side (m)")
    p.add_argument("--density", type=float, default=10.0, help="points per m² (all returns)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--crs", default="EPSG:25831")
    p.add_argument("--x0", type=float, default=400000.0, help="zone lower-left x")
    p.add_argument("--y0", type=float, default=4600000.0, help="zone lower-left y")
    p.add_argument("--preset", default="catalonia", help="catalonia|flat|mountain|urban|test")
    p.add_argument("--edge-tower", action="store_true", help="put one tower on an inner block edge")
    p.add_argument("--tower-source", default="synthetic", choices=["synthetic", "real", "mixed"])
    p.add_argument("--real-towers", default=None, help="real tower sets (../shared/data/real/towers)")
    p.add_argument("--real-backgrounds", default=None, help="real background tiles dir (*.laz)")
    p.add_argument("--parallel", action="store_true", help="multi-threaded LAZ compression")
    p.set_defaults(func=_synth)
    r = subparsers.add_parser("synth-report", help="realism report of a synthetic zone (PNGs + report.md)")
    r.add_argument("--zone", required=True, help="zone directory written by `towerpipe synth`")
    r.add_argument("--out", required=True, help="report directory")
    r.add_argument("--real-towers", default=None, help="also profile the real tower sets in this dir")
    r.add_argument("--density", type=float, default=10.0, help="density for resampling real towers")
    r.set_defaults(func=_report)
