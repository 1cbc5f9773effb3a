"""Realism report of a synthetic zone (paper Fig. 3 and Fig. 5 counterparts).

HAG CDFs of all points, tower points and per-tower maxima; the points-per-tower
histogram; the same for the real tower sets resampled to airborne density.
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from towerpipe import classes
from towerpipe.errors import InputError  # noqa: E402
from towerpipe.synth.terrain import Terrain  # noqa: E402


def _cdf(ax, v, label):
    v = np.asarray(v)
    if len(v) > 200_000:  # an evenly spaced subsample draws the same curve
        v = np.sort(v)[np.linspace(0, len(v) - 1, 200_000).astype(np.int64)]
    v = np.sort(v)
    if len(v):
        ax.plot(v, np.arange(1, len(v) + 1) / len(v), label=label)


def zone_stats(zone: str | Path) -> dict:
    """HAG of all non-noise points, of tower points, per-tower maxima and counts."""
    zone = Path(zone)
    files = sorted(zone.glob("*.laz"))
    if not files:
        raise InputError(zone, "no *.laz block in the zone directory")
    tpath = zone / "terrain.npz"
    terrain = Terrain.load(tpath) if tpath.exists() else None
    hag_all, hag_t, tid_t, cls_all = [], [], [], []
    for f in files:
        las = laspy.read(f)
        x, y, z = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
        cls = np.asarray(las.classification)
        if terrain is not None:
            g = terrain.z(x, y)
        else:  # real backgrounds: interpolate from ground points
            from towerpipe.synth.background import ground_fn

            g = ground_fn(np.c_[x, y, z], cls)(x, y)
        hag = z - g
        ok = ~np.isin(cls, classes.NOISE)
        hag_all.append(hag[ok])
        cls_all.append(cls[ok])
        tid = np.asarray(las["TowerId"])
        hag_t.append(hag[tid > 0])
        tid_t.append(tid[tid > 0])
    hag_all, cls_all = np.concatenate(hag_all), np.concatenate(cls_all)
    hag_t, tid_t = np.concatenate(hag_t), np.concatenate(tid_t)
    ids, inv = np.unique(tid_t, return_inverse=True)
    maxima = np.full(len(ids), -np.inf)
    np.maximum.at(maxima, inv, hag_t)
    counts = np.bincount(inv, minlength=len(ids))
    ng = ~np.isin(cls_all, [2, 11])
    return {
        "hag_all": hag_all,
        "hag_nonground": hag_all[ng],
        "hag_tower": hag_t,
        "tower_max": maxima,
        "tower_counts": counts,
    }


def real_tower_stats(root: str | Path, density: float, seed: int = 0) -> dict:
    """Per-tower maxima and point counts of the real tower sets after airborne resampling."""
    from towerpipe.synth.real import airborne_resample, load_real_towers

    rng = np.random.default_rng(seed)
    items = load_real_towers(root)
    hs, ns, hag = [], [], []
    for _, s in items:
        p = airborne_resample(s, density, rng)
        if len(p):
            hs.append(p[:, 2].max())
            ns.append(len(p))
            hag.append(p[:, 2])
    return {
        "tower_max": np.array(hs),
        "tower_counts": np.array(ns),
        "hag_tower": np.concatenate(hag) if hag else np.zeros(0),
    }


def realism_report(
    zone: str | Path, out: str | Path, real_towers: str | Path | None = None, density: float = 10.0
) -> Path:
    """Write ``hag_cdf.png``, ``points_per_tower.png`` and ``report.md`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = zone_stats(zone)
    r = real_tower_stats(real_towers, density) if real_towers else None
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    _cdf(axes[0], s["hag_all"], "all points")
    _cdf(axes[0], s["hag_nonground"], "non-ground points")
    _cdf(axes[1], s["hag_tower"], "synthetic towers")
    _cdf(axes[2], s["tower_max"], "synthetic towers")
    if r is not None:
        _cdf(axes[1], r["hag_tower"], "real towers (resampled)")
        _cdf(axes[2], r["tower_max"], "real towers (resampled)")
    for ax, title in zip(axes, ["(a) HAG of all points", "(b) HAG of tower points", "(c) max HAG per tower"]):
        for v in (3, 8):
            ax.axvline(v, ls=":", c="k")
        ax.set_title(title)
        ax.set_xlabel("height above ground (m)")
        ax.set_xlim(-1, 55)
        ax.legend(fontsize=8, loc="lower right")
    axes[0].set_ylabel("CDF")
    fig.tight_layout()
    fig.savefig(out / "hag_cdf.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    bins = np.linspace(0, 2500, 26)
    ax.hist(s["tower_counts"], bins=bins, alpha=0.7, label="synthetic")
    if r is not None:
        ax.hist(r["tower_counts"], bins=bins, alpha=0.5, label=f"real, resampled to {density:g} pts/m²")
    ax.set_xlabel("points per tower")
    ax.set_ylabel("towers")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "points_per_tower.png", dpi=110)
    plt.close(fig)
    ng = s["hag_nonground"]
    share = float(np.mean((ng >= 3) & (ng < 8))) if len(ng) else float("nan")
    share_all = float(np.mean((s["hag_all"] >= 3) & (s["hag_all"] < 8)))
    share_t = float(np.mean((s["hag_tower"] >= 3) & (s["hag_tower"] < 8))) if len(s["hag_tower"]) else float("nan")
    c = s["tower_counts"]
    lines = [
        "# Synthetic zone realism report",
        "",
        f"zone: `{zone}`",
        "",
        "| figure | value | paper |",
        "|---|---|---|",
        f"| share of non-ground points with 3 ≤ HAG < 8 m | {share:.1%} | 40–75 % (Fig. 3a) |",
        f"| share of all points with 3 ≤ HAG < 8 m | {share_all:.1%} | |",
        f"| share of tower points with 3 ≤ HAG < 8 m | {share_t:.1%} | about half of (a) (Fig. 3b) |",
        f"| towers | {len(c)} | |",
        f"| points per tower: min / median / max | {c.min() if len(c) else 0} / "
        f"{np.median(c) if len(c) else 0:.0f} / {c.max() if len(c) else 0} | 1–2434 (Fig. 5) |",
        f"| max HAG per tower: min / median / max (m) | {s['tower_max'].min() if len(c) else 0:.1f} / "
        f"{np.median(s['tower_max']) if len(c) else 0:.1f} / {s['tower_max'].max() if len(c) else 0:.1f} | ≥ 10 |",
    ]
    if r is not None and len(r["tower_counts"]):
        rc = r["tower_counts"]
        lines += [
            f"| real towers at {density:g} pts/m²: n / median points / median max HAG | {len(rc)} / "
            f"{np.median(rc):.0f} / {np.median(r['tower_max']):.1f} m | |"
        ]
    lines += ["", "![HAG CDFs](hag_cdf.png)", "", "![points per tower](points_per_tower.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    (out / "report.json").write_text(
        json.dumps(
            {
                "share_nonground_3_8": share,
                "share_all_3_8": share_all,
                "share_tower_3_8": share_t,
                "median_points_per_tower": float(np.median(c)) if len(c) else 0.0,
                "n_towers": int(len(c)),
            },
            indent=1,
        )
    )
    return path
