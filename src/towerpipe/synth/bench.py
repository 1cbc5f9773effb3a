"""Benchmark: one 1 km² block at 10 pts/m², LAZ writing included.

Run ``python -m towerpipe.synth.bench [--size 1000] [--density 10] [--parallel]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path


def run_bench(size: float = 1000.0, density: float = 10.0, seed: int = 0, parallel: bool = False) -> dict:
    """Generate and write one block; return seconds, points and points/s."""
    from towerpipe.synth.zone import generate_zone

    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        truth = generate_zone(Path(d), seed=seed, blocks=1, size=size, density=density, parallel=parallel)
        dt = time.perf_counter() - t0
        mb = sum(Path(b["path"]).stat().st_size for b in truth.blocks) / 1e6
    n = sum(b["n_points"] for b in truth.blocks)
    return {"seconds": dt, "points": n, "points_per_s": n / dt, "laz_mb": mb, "towers": len(truth.towers)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=1000.0)
    ap.add_argument("--density", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--parallel", action="store_true")
    a = ap.parse_args(argv)
    r = run_bench(a.size, a.density, a.seed, a.parallel)
    print(
        f"synth bench: {a.size:.0f} m block at {a.density} pts/m²: {r['points']} points in "
        f"{r['seconds']:.2f} s = {r['points_per_s']:.0f} points/s ({r['laz_mb']:.1f} MB LAZ, {r['towers']} towers)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
