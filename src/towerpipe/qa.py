"""Quality-assurance pages: one self-contained HTML page (+ JSON) per block, and a zone index.

:func:`block_report` gathers the numbers of one block (points per stage, ground,
density, HAG, windows, towers, timings and memory, accuracy against input labels
when there are any), decides whether the block needs a human look (see
:data:`DEFAULT_LIMITS`), and writes

* ``out_html``: a page with inline CSS and embedded base64 PNG plots (no external
  assets: it can be mailed or opened from a network share);
* ``out_json``: every number on the page, read by :func:`zone_index`.

:func:`zone_index` lists all blocks of a zone with totals, failed jobs and the
blocks flagged for a look, with their reasons.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.assemble import write_text_atomic
from towerpipe.towers import f1_score, match_towers, towers_from_labels

#: Limits that flag a block or a tower for a human look; override via ``limits=``.
DEFAULT_LIMITS: dict[str, float] = {
    "min_density": 2.0,            # median points / m² over non-empty cells
    "min_ground_ratio": 0.05,      # share of points classified ground
    "edge_margin_m": 5.0,          # tower centroid closer than this to the block edge
    "min_tower_prob": 0.6,         # mean probability of a tower's points
    "min_wire_support": 0.5,       # conductor support of a tower (a low tower is kept without it)
    "max_gate_ratio": 0.25,        # share of windows that passed the classifier gate
    "min_recall": 1.0,             # tower recall against input labels (when present)
    "min_precision": 1.0,          # tower precision against input labels (when present)
    "min_truth_points": 20,        # labelled clusters with fewer points are not towers (paper: < 20 dropped)
}

TOWER_CLASS = 15
GROUND_CLASS = 2

_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"DejaVu Sans",Arial,sans-serif;margin:0;color:#1f2933;background:#f5f7fa}
main{max-width:1180px;margin:0 auto;padding:18px 26px 40px}
h1{font-size:1.55em;margin:.2em 0 .1em}h2{font-size:1.15em;margin:1.6em 0 .5em;border-bottom:2px solid #d9e2ec;padding-bottom:.2em}
.sub{color:#616e7c;font-size:.9em;margin-bottom:.8em}
.summary{font-size:1.1em;padding:12px 16px;border-radius:6px;margin:10px 0 6px;border-left:6px solid}
.summary.ok{background:#e3f9e5;border-color:#31b237}.summary.look{background:#fff3c4;border-color:#f0b429}
.summary.fail{background:#ffe3e3;border-color:#e12d39}
.cards{display:flex;flex-wrap:wrap;gap:10px;margin:12px 0}
.card{background:#fff;border:1px solid #d9e2ec;border-radius:6px;padding:8px 14px;min-width:120px}
.card .v{font-size:1.35em;font-weight:600}.card .k{color:#616e7c;font-size:.8em}
table{border-collapse:collapse;background:#fff;font-size:.88em;margin:4px 0 8px}
th,td{border:1px solid #d9e2ec;padding:4px 9px;text-align:left;vertical-align:top}
th{background:#f0f4f8;font-weight:600}td.n,th.n{text-align:right;font-variant-numeric:tabular-nums}
tr.look td{background:#fffbea}tr.fail td{background:#fff5f5}tr.total td{font-weight:600;background:#f0f4f8}
.flag{display:inline-block;background:#fff3c4;border:1px solid #f0b429;border-radius:3px;padding:0 5px;margin:1px 2px;font-size:.85em}
.flag.fail{background:#ffe3e3;border-color:#e12d39}
.ok{color:#207227}.grid{display:flex;flex-wrap:wrap;gap:16px;align-items:flex-start}
figure{margin:0;background:#fff;border:1px solid #d9e2ec;border-radius:6px;padding:6px}
figcaption{color:#616e7c;font-size:.82em;padding:2px 4px}img{display:block;max-width:100%}
ul.warn li{margin:2px 0}.muted{color:#9aa5b1}code{font-family:"DejaVu Sans Mono",Menlo,Consolas,monospace;font-size:.95em}
footer{color:#9aa5b1;font-size:.8em;margin-top:30px}
"""


# --------------------------------------------------------------------------- small helpers
def _esc(v: Any) -> str:
    return html.escape(str(v), quote=True)


def _fmt(v: Any, digits: int = 1) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}".replace(",", "\u202f")
    if isinstance(v, (float, np.floating)):
        return f"{float(v):,.{digits}f}".replace(",", "\u202f")
    return _esc(v)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(float(obj)) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _png(fig: Any) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _figure(src: str, caption: str) -> str:
    return f'<figure><img src="{src}" alt="{_esc(caption)}"><figcaption>{_esc(caption)}</figcaption></figure>'


def _table(headers: Sequence[str], rows: Iterable[Sequence[Any]], numeric: Sequence[bool] | None = None,
           row_classes: Sequence[str] | None = None) -> str:
    numeric = list(numeric or [False] * len(headers))
    head = "".join(f'<th class="{"n" if n else ""}">{_esc(h)}</th>' for h, n in zip(headers, numeric))
    body = []
    for i, row in enumerate(rows):
        cls = f' class="{row_classes[i]}"' if row_classes and row_classes[i] else ""
        cells = "".join(f'<td class="{"n" if n else ""}">{c}</td>' for c, n in zip(row, numeric))
        body.append(f"<tr{cls}>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


# --------------------------------------------------------------------------- inputs
def load_classified(src: str | os.PathLike[str] | Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Points of a classified block: ``x, y, z, classification`` and, when present, ``prob``, ``hag``.

    Parameters
    ----------
    src
        A mapping of arrays, or the path of the classified LAS/LAZ written by the
        merge step (``prob`` from its ``TowerProbability`` extra dimension).
    """
    if isinstance(src, Mapping):
        out = {k: np.asarray(v) for k, v in src.items()}
    else:
        import laspy

        las = laspy.read(src)
        out = {"x": np.asarray(las.x), "y": np.asarray(las.y), "z": np.asarray(las.z),
               "classification": np.asarray(las.classification, dtype=np.uint8)}
        names = {n.lower(): n for n in las.point_format.extra_dimension_names}
        if "towerprobability" in names:
            out["prob"] = np.asarray(las[names["towerprobability"]], dtype=np.float32)
    missing = [k for k in ("x", "y", "z", "classification") if k not in out]
    if missing:
        raise ValueError(f"classified points lack {missing}")
    return out


def read_benchmark(path: str | os.PathLike[str]) -> dict[str, float]:
    """Wall time ``s`` and peak memory ``max_rss`` (MB) of a Snakemake benchmark TSV.

    With several repetitions (rows) the mean time and the largest peak are used;
    columns that are missing or ``NA``/``-`` are left out.
    """
    lines = [ln.rstrip("\n").split("\t") for ln in Path(path).read_text().splitlines() if ln.strip()]
    if len(lines) < 2:
        return {}
    head, rows = lines[0], lines[1:]
    out: dict[str, float] = {}
    for col, key, agg in (("s", "seconds", np.mean), ("max_rss", "max_rss_mb", np.max),
                          ("cpu_time", "cpu_seconds", np.mean)):
        if col in head:
            vals = []
            for r in rows:
                try:
                    vals.append(float(r[head.index(col)]))
                except (ValueError, IndexError):
                    pass
            if vals:
                out[key] = float(agg(vals))
    return out


def _read_towers(towers: Any) -> Any:
    import geopandas as gpd

    if towers is None:
        from towerpipe.towers import empty_towers

        return empty_towers()
    if isinstance(towers, (str, os.PathLike)):
        from towerpipe.gpkg import read_towers

        return read_towers(towers)
    return gpd.GeoDataFrame(towers)


def _sum_dicts(dicts: Iterable[Mapping[str, Any] | None]) -> dict[str, float]:
    out: dict[str, float] = {}
    for d in dicts:
        for k, v in (d or {}).items():
            if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
                out[k] = out.get(k, 0) + v
    return out


# --------------------------------------------------------------------------- rasters and plots
def _fill_nearest(grid: np.ndarray) -> np.ndarray:
    from scipy.ndimage import distance_transform_edt

    bad = ~np.isfinite(grid)
    if not bad.any() or bad.all():
        return np.where(bad, 0.0, grid)
    idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
    return grid[tuple(idx)]


def _max_z_grid(x: np.ndarray, y: np.ndarray, z: np.ndarray, bounds: Sequence[float],
                max_cells: int = 700) -> tuple[np.ndarray, float]:
    """Max z per cell (north up), cell size chosen so the longer side has <= ``max_cells`` cells."""
    xmin, ymin, xmax, ymax = bounds
    cell = max(1.0, max(xmax - xmin, ymax - ymin) / max_cells)
    nx = max(1, int(math.ceil((xmax - xmin) / cell)))
    ny = max(1, int(math.ceil((ymax - ymin) / cell)))
    ix = np.clip(((x - xmin) / cell).astype(np.int64), 0, nx - 1)
    iy = np.clip(((ymax - y) / cell).astype(np.int64), 0, ny - 1)
    grid = np.full(ny * nx, -np.inf)
    np.maximum.at(grid, iy * nx + ix, z)
    grid = grid.reshape(ny, nx)
    grid[~np.isfinite(grid)] = np.nan
    return grid, cell


def _raster_grid(path: str | os.PathLike[str], max_cells: int = 900) -> tuple[np.ndarray, list[float], float]:
    """Band 1 of a DTM/DSM (decimated to <= ``max_cells`` per side), its bounds and cell size."""
    import rasterio

    with rasterio.open(path) as ds:
        f = max(1, int(math.ceil(max(ds.width, ds.height) / max_cells)))
        shape = (max(1, ds.height // f), max(1, ds.width // f))
        band = ds.read(1, out_shape=shape, masked=True).astype(np.float64)
        b = ds.bounds
        cell = abs(ds.transform.a) * ds.width / shape[1]
    return band.filled(np.nan), [b.left, b.bottom, b.right, b.top], cell


def _hillshade(grid: np.ndarray, cell: float) -> np.ndarray:
    from matplotlib.colors import LightSource

    return LightSource(azdeg=315, altdeg=45).hillshade(_fill_nearest(grid), vert_exag=1.0, dx=cell, dy=cell)


def _plot_map(towers: Any, bounds: Sequence[float] | None, grid: np.ndarray | None,
              grid_bounds: Sequence[float] | None, cell: float, source: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.6, 7.2))
    if grid is not None and np.isfinite(grid).any():
        gb = grid_bounds
        ax.imshow(_hillshade(grid, cell), cmap="gray", extent=(gb[0], gb[2], gb[1], gb[3]), vmin=0, vmax=1)
        ax.imshow(_fill_nearest(grid), cmap="terrain", alpha=0.25, extent=(gb[0], gb[2], gb[1], gb[3]))
    if bounds is not None:
        xmin, ymin, xmax, ymax = bounds
        ax.plot([xmin, xmax, xmax, xmin, xmin], [ymin, ymin, ymax, ymax, ymin], color="#1f2933", lw=1.2, ls="--")
    for i, (geom, cx, cy) in enumerate(zip(towers.geometry, towers["centroid_x"], towers["centroid_y"]), 1):
        xs, ys = geom.exterior.xy
        ax.fill(xs, ys, facecolor="#e12d39", alpha=0.35, edgecolor="#a50f15", lw=1.5)
        ax.plot(cx, cy, marker="^", color="#a50f15", ms=9, mec="white", mew=1)
        ax.annotate(str(i), (cx, cy), xytext=(6, 6), textcoords="offset points", fontsize=11, weight="bold",
                    color="#1f2933", bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "#a50f15", "alpha": 0.9})
    ax.set_aspect("equal")
    if bounds is not None:
        pad = 0.02 * max(bounds[2] - bounds[0], bounds[3] - bounds[1], 1.0)
        ax.set_xlim(bounds[0] - pad, bounds[2] + pad)
        ax.set_ylim(bounds[1] - pad, bounds[3] + pad)
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=8)
    ax.set_xlabel("easting (m)")
    ax.set_ylabel("northing (m)")
    ax.set_title(f"Towers found (red, numbered as in the table) over a hillshade of {source}", fontsize=10)
    return _png(fig)


def _plot_density(x: np.ndarray, y: np.ndarray, bounds: Sequence[float]) -> tuple[str, dict[str, float]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xmin, ymin, xmax, ymax = bounds
    cell = max(2.0, max(xmax - xmin, ymax - ymin) / 120)
    nx = max(1, int(math.ceil((xmax - xmin) / cell)))
    ny = max(1, int(math.ceil((ymax - ymin) / cell)))
    # points per cell by integer binning (np.histogram2d is ~10x slower on millions of points)
    ix = np.clip(((np.asarray(x) - xmin) * (1.0 / cell)).astype(np.int32), 0, nx - 1)
    iy = np.clip(((np.asarray(y) - ymin) * (1.0 / cell)).astype(np.int32), 0, ny - 1)
    ix *= ny
    ix += iy
    h = np.bincount(ix, minlength=nx * ny).reshape(nx, ny).astype(np.float64)
    dens = h.T[::-1] / (cell * cell)
    filled = dens[dens > 0]
    stats = {
        "density_cell_m": float(cell),
        "density_median": float(np.median(filled)) if filled.size else 0.0,
        "density_p05": float(np.percentile(filled, 5)) if filled.size else 0.0,
        "empty_cells_pct": float(100.0 * (dens == 0).mean()),
    }
    fig, ax = plt.subplots(figsize=(5.4, 4.6))
    vmax = max(1.0, float(np.percentile(filled, 98))) if filled.size else 1.0
    im = ax.imshow(dens, extent=(xmin, xmin + nx * cell, ymin, ymin + ny * cell), cmap="viridis", vmin=0, vmax=vmax)
    fig.colorbar(im, ax=ax, shrink=0.85, label="points / m²")
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    ax.set_title(f"Point density ({cell:.0f} m cells)", fontsize=10)
    return _png(fig), stats


def _plot_hag(hag: np.ndarray, tower: np.ndarray | None) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.4, 4.2))
    ok = np.isfinite(hag)
    tower = tower[ok] if tower is not None and len(tower) == len(hag) else None
    hag = hag[ok]
    hi = max(10.0, float(np.percentile(hag, 99.9))) if hag.size else 10.0
    rng = (min(-2.0, float(hag.min()) if hag.size else -2.0), hi)
    # equal-width bins given as (count, range): numpy's fast path, no per-point search
    counts, edges = np.histogram(np.clip(hag, *rng), bins=79, range=rng)
    ax.stairs(counts, edges, fill=True, color="#829ab1", label="all points")
    if tower is not None and tower.any():
        ax.stairs(np.histogram(np.clip(hag[tower], *rng), bins=79, range=rng)[0], edges, fill=True,
                  color="#e12d39", alpha=0.8, label="classified tower (15)")
    for b in (3.0, 8.0):
        ax.axvline(b, color="#616e7c", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_xlabel("height above ground (m)")
    ax.set_ylabel("points (log)")
    ax.legend(fontsize=8)
    ax.set_title("Height above ground (dotted: 3 m / 8 m sampling bands)", fontsize=10)
    return _png(fig)


# --------------------------------------------------------------------------- the block page
def _with_neighbour_towers(m: dict[str, Any], truth: Any, neighbour_towers: Sequence[Mapping[str, Any]]
                           ) -> dict[str, Any]:
    """Recall counting labelled towers matched by a neighbour-owned tower as found."""
    import geopandas as gpd
    import shapely

    nb = gpd.GeoDataFrame({"tower_id": [t["tower_id"] for t in neighbour_towers]},
                          geometry=shapely.from_wkt([t["footprint_wkt"] for t in neighbour_towers]), crs=truth.crs)
    left = truth[truth["tower_id"].astype(str).isin(m["unmatched_truth"])]
    extra = match_towers(nb, left, max_dist=5.0)["matches"] if len(left) else []
    found = {x["truth"] for x in extra}
    tp_recall = m["tp"] + len(extra)
    m = dict(m, fn=len(truth) - tp_recall, recall=tp_recall / len(truth),
             matches=[*m["matches"], *({**x, "owner": "neighbour"} for x in extra)],
             unmatched_truth=[t for t in m["unmatched_truth"] if t not in found])
    m["f1"] = f1_score(m["precision"], m["recall"])
    return m


def block_report(
    out_html: str | os.PathLike[str],
    out_json: str | os.PathLike[str],
    *,
    block_name: str,
    zone: str = "",
    block_bounds: Sequence[float] | None = None,
    stats: Mapping[str, Any] | None = None,
    tile_metas: Sequence[Mapping[str, Any]] = (),
    pred_metas: Sequence[Mapping[str, Any]] = (),
    towers: Any = None,
    classified: str | os.PathLike[str] | Mapping[str, np.ndarray] | None = None,
    raster: str | os.PathLike[str] | None = None,
    truth: np.ndarray | None = None,
    timings: Mapping[str, float | str | os.PathLike[str] | Mapping[str, Any]] | None = None,
    warnings: Sequence[str] = (),
    limits: Mapping[str, float] | None = None,
    neighbour_towers: Sequence[Mapping[str, Any]] | None = None,
) -> dict[str, Any]:
    """Write the QA page and its JSON for one block.

    Parameters
    ----------
    out_html, out_json
        Destinations (written atomically).
    block_name, zone
        Names shown on the page.
    block_bounds
        ``(xmin, ymin, xmax, ymax)`` of the block (default: the points' extent).
    stats
        Extra numbers of the block (e.g. from the merge step), shown as a table and
        kept in the JSON.
    tile_metas, pred_metas
        ``meta`` dicts of the block's tile files and prediction files (counts,
        ``ground_source``, windows, timings, ``peak_rss_mb``, model).
    towers
        The block's towers: GeoDataFrame from :func:`towerpipe.towers.extract_towers`
        or the path of the block's tower GeoPackage.
    classified
        The classified points (mapping with ``x, y, z, classification`` and
        optionally ``prob``, ``hag``) or the path of the classified LAZ.
    raster
        A DTM/DSM GeoTIFF for the hillshade (default: max z of the points per cell).
    truth
        Input class labels of the points (Classification before it was
        overwritten), same order as ``classified``; towers are class 15. When it
        holds class 15, tower precision/recall and point IoU are reported.
    timings
        Stage name → seconds, or → path of a Snakemake benchmark TSV (``s``, ``max_rss``).
    warnings
        Messages to show (e.g. logged warnings of the block's jobs).
    limits
        Overrides of :data:`DEFAULT_LIMITS`.
    neighbour_towers
        Towers with points in this block that a neighbouring block owns (``tower_id``,
        ``footprint_wkt``): a labelled tower they match counts as found (recall), not as
        a tower of this block (precision).

    Returns
    -------
    dict
        The numbers written to ``out_json`` (``status`` is ``"ok"`` or ``"look"``,
        ``flags`` lists the reasons).
    """
    lim = dict(DEFAULT_LIMITS, **(limits or {}))
    out_html, out_json = Path(out_html), Path(out_json)
    gdf = _read_towers(towers)
    pts = load_classified(classified) if classified is not None else None
    flags: list[dict[str, str]] = []

    def flag(code: str, reason: str) -> None:
        flags.append({"code": code, "reason": reason})

    # ---- extent
    if block_bounds is None:
        cb = [m.get("core_bounds") for m in tile_metas if m.get("core_bounds")]
        if cb:
            arr = np.asarray(cb, dtype=float)
            block_bounds = [arr[:, 0].min(), arr[:, 1].min(), arr[:, 2].max(), arr[:, 3].max()]
        elif pts is not None and len(pts["x"]):
            block_bounds = [pts["x"].min(), pts["y"].min(), pts["x"].max(), pts["y"].max()]
    bounds = [float(v) for v in block_bounds] if block_bounds is not None else None
    area_m2 = (bounds[2] - bounds[0]) * (bounds[3] - bounds[1]) if bounds else None

    # ---- points and ground
    tile_counts = _sum_dicts(m.get("counts") for m in tile_metas)
    ground_sources = sorted({str(m.get("ground_source")) for m in tile_metas if m.get("ground_source")})
    ground_classified = any(s != "class2" for s in ground_sources)
    n_points = int(len(pts["x"])) if pts is not None else None
    cls = pts["classification"] if pts is not None else None
    # the ground the pipeline used (class 2, or PDAL's when it had to classify), else class 2
    n_ground = (int(tile_counts["ground_core"]) if "ground_core" in tile_counts else
                int(np.count_nonzero(cls == GROUND_CLASS)) if cls is not None else None)
    n_tower_pts = int(np.count_nonzero(cls == TOWER_CLASS)) if cls is not None else None
    ground_ratio = (n_ground / n_points) if n_points else None
    if ground_classified:
        flag("ground_classified", f"input had no usable ground class; ground classified by towerpipe "
                                  f"({', '.join(s for s in ground_sources if s != 'class2')})")
    if ground_ratio is not None and ground_ratio < lim["min_ground_ratio"]:
        flag("low_ground", f"only {100 * ground_ratio:.1f} % of points are ground")

    # ---- windows, model
    win = {k: int(sum(int(m.get(k) or 0) for m in pred_metas))
           for k in ("windows_total", "windows_passed_gate", "windows_segmented")}
    gate_ratio = win["windows_passed_gate"] / win["windows_total"] if win["windows_total"] else None
    if gate_ratio is not None and gate_ratio > lim["max_gate_ratio"]:
        flag("many_windows_gated", f"{100 * gate_ratio:.0f} % of windows passed the classifier gate "
                                   f"(> {100 * lim['max_gate_ratio']:.0f} %)")
    model = next((m.get("model") for m in pred_metas if m.get("model")), None) or {}
    points_model_input = int(sum(int(m.get("points_model_input_core") or 0) for m in pred_metas))

    # ---- per-stage counts
    stage_counts: list[tuple[str, int]] = [(f"tiles: {k.replace('_', ' ')}", int(v)) for k, v in tile_counts.items()]
    if pred_metas:
        stage_counts.append(("model input (core points)", points_model_input))
    if n_points is not None:
        stage_counts += [("output: all points", n_points), ("output: ground (class 2)", n_ground),
                         ("output: tower (class 15)", n_tower_pts)]
    stage_counts.append(("towers", int(len(gdf))))

    # ---- plots and density
    figures: list[str] = []
    density: dict[str, float] = {}
    if pts is not None and n_points and bounds:
        src, density = _plot_density(pts["x"], pts["y"], bounds)
        density["mean"] = n_points / area_m2 if area_m2 else None
        figures.append(_figure(src, "Point density: look for stripes, holes and low-density corners"))
        if density["density_median"] < lim["min_density"]:
            flag("low_density", f"median density {density['density_median']:.1f} pts/m² "
                                f"(< {lim['min_density']:.1f})")
    hag = None
    hag_source = None
    if pts is not None and "hag" in pts:
        hag, hag_source = np.asarray(pts["hag"], dtype=np.float64), "HAG of the pipeline"
    elif pts is not None and raster is not None:
        import rasterio

        with rasterio.open(raster) as ds:
            rows, cols = rasterio.transform.rowcol(ds.transform, pts["x"], pts["y"])
            rows = np.clip(np.asarray(rows), 0, ds.height - 1)
            cols = np.clip(np.asarray(cols), 0, ds.width - 1)
            dtm = ds.read(1, masked=True).astype(np.float64).filled(np.nan)
            hag, hag_source = pts["z"] - dtm[rows, cols], f"z − {Path(raster).name}"
    if hag is not None:
        figures.append(_figure(_plot_hag(hag, cls == TOWER_CLASS if cls is not None else None),
                               f"Height above ground ({hag_source})"))
    if raster is not None:
        grid, gb, cell = _raster_grid(raster)
        map_src = Path(raster).name
    elif pts is not None and n_points and bounds:
        grid, cell = _max_z_grid(pts["x"], pts["y"], pts["z"], bounds)
        gb, map_src = bounds, "max point z per cell"
    else:
        grid, gb, cell, map_src = None, None, 1.0, "nothing (no points given)"
    map_png = _plot_map(gdf, bounds, grid, gb, cell, map_src) if (bounds or len(gdf)) else None

    # ---- towers
    tower_rows = []
    for i, r in enumerate(gdf.itertuples(index=False), 1):
        tflags = []
        if r.edge_distance_m < lim["edge_margin_m"]:
            tflags.append(f"{r.edge_distance_m:.1f} m from block edge")
        if r.prob_mean < lim["min_tower_prob"]:
            tflags.append(f"low mean probability {r.prob_mean:.2f}")
        support = float(getattr(r, "wire_support", float("nan")))
        if math.isfinite(support) and support < lim["min_wire_support"]:
            tflags.append(f"no conductors found (support {support:.2f}): a pole, or not a tower?")
        for t in tflags:
            flag("tower", f"tower {i} ({r.tower_id}): {t}")
        tower_rows.append({"n": i, "tower_id": r.tower_id, "x": r.centroid_x, "y": r.centroid_y,
                           "height_m": r.height_m, "base_z": r.base_z, "n_points": int(r.n_points),
                           "prob_mean": r.prob_mean, "prob_max": r.prob_max,
                           "wire_support": support, "blocks": r.blocks,
                           "edge_distance_m": r.edge_distance_m, "flags": tflags})

    # ---- accuracy against input labels
    accuracy = None
    if truth is not None and pts is not None:
        truth = np.asarray(truth)
        t_mask = truth.astype(bool) if truth.dtype == bool else truth == TOWER_CLASS
        if len(t_mask) != n_points:
            raise ValueError(f"truth has {len(t_mask)} labels for {n_points} points")
        if t_mask.any():
            p_mask = cls == TOWER_CLASS
            inter = int(np.count_nonzero(p_mask & t_mask))
            union = int(np.count_nonzero(p_mask | t_mask))
            true_towers = towers_from_labels(pts["x"], pts["y"], pts["z"], pts.get("hag"), t_mask,
                                             min_points=int(lim["min_truth_points"]))
            if bounds is not None and len(true_towers):
                c = true_towers.geometry.centroid
                inside = (c.x >= bounds[0]) & (c.x < bounds[2]) & (c.y >= bounds[1]) & (c.y < bounds[3])
                true_towers = true_towers[inside.to_numpy()]
            m = match_towers(gdf, true_towers, max_dist=5.0)
            if neighbour_towers and len(true_towers):
                m = _with_neighbour_towers(m, true_towers, neighbour_towers)
            accuracy = {"point_iou": inter / union if union else None, "points_true": int(t_mask.sum()),
                        "points_pred": int(p_mask.sum()), "points_both": inter,
                        "towers_true": int(len(true_towers)),
                        **{k: m[k] for k in ("precision", "recall", "f1", "tp", "fp", "fn", "matches")}}
            if m["recall"] is not None and m["recall"] < lim["min_recall"]:
                flag("missed_towers", f"{m['fn']} of {len(true_towers)} labelled towers not found "
                                      f"(recall {m['recall']:.2f})")
            if m["precision"] is not None and m["precision"] < lim["min_precision"]:
                flag("false_towers", f"{m['fp']} of {len(gdf)} towers found match no labelled tower "
                                     f"(precision {m['precision']:.2f})")

    # ---- timings and memory
    stage_time: list[dict[str, Any]] = []
    for label, metas in (("preprocess (tiles)", tile_metas), ("inference (tiles)", pred_metas)):
        sums = _sum_dicts(m.get("timings") for m in metas)
        for k, v in sums.items():
            stage_time.append({"stage": f"{label}: {k}", "seconds": float(v), "max_rss_mb": None})
    rss = [float(m["peak_rss_mb"]) for m in pred_metas if m.get("peak_rss_mb") is not None]
    if rss:
        stage_time.append({"stage": "inference: peak of tile jobs", "seconds": None, "max_rss_mb": max(rss)})
    for name, v in (timings or {}).items():
        if isinstance(v, (str, os.PathLike)):
            try:
                b = read_benchmark(v)
            except OSError as exc:
                warnings = [*warnings, f"benchmark file of {name} unreadable: {exc}"]
                continue
            stage_time.append({"stage": name, "seconds": b.get("seconds"), "max_rss_mb": b.get("max_rss_mb")})
        elif isinstance(v, Mapping):  # aggregated over several jobs: {"seconds", "max_rss_mb", "jobs"}
            label = f"{name} ({v['jobs']} jobs)" if v.get("jobs", 1) > 1 else name
            stage_time.append({"stage": label, "seconds": v.get("seconds"), "max_rss_mb": v.get("max_rss_mb")})
        else:
            stage_time.append({"stage": name, "seconds": float(v), "max_rss_mb": None})
    warnings = [str(w) for w in warnings]
    if warnings:
        flag("warnings", f"{len(warnings)} warning(s) during processing")

    status = "look" if flags else "ok"
    n_look_towers = sum(1 for t in tower_rows if t["flags"])
    summary = _block_summary(len(gdf), n_look_towers, flags)
    doc = {
        "block": block_name, "zone": zone, "status": status, "summary": summary, "flags": flags,
        "html": out_html.name, "generated_at": datetime.now(timezone.utc).replace(microsecond=0).isoformat(),
        "bounds": bounds, "area_m2": area_m2,
        "points": n_points, "points_ground": n_ground, "points_tower": n_tower_pts, "ground_ratio": ground_ratio,
        "ground_sources": ground_sources, "ground_classified": ground_classified,
        "density": density, "stage_counts": dict(stage_counts), "tile_counts": tile_counts,
        "tiles": len(tile_metas), "pred_files": len(pred_metas), **win, "gate_ratio": gate_ratio,
        "points_model_input": points_model_input if pred_metas else None,
        "model": {k: model.get(k) for k in ("name", "version", "feature_set", "sha256") if k in model},
        "towers": tower_rows, "n_towers": len(gdf),
        "tower_prob_mean": float(gdf["prob_mean"].mean()) if len(gdf) else None,
        "accuracy": accuracy, "timings": stage_time, "warnings": warnings, "stats": dict(stats or {}),
        "limits": lim,
    }
    doc = _jsonable(doc)
    write_text_atomic(out_json, json.dumps(doc, indent=1))
    write_text_atomic(out_html, _block_html(doc, map_png, figures))
    return doc


def _block_summary(n_towers: int, n_look_towers: int, flags: list[dict[str, str]]) -> str:
    s = f"{n_towers} tower{'s' if n_towers != 1 else ''} found"
    if n_look_towers:
        s += f"; {n_look_towers} need{'s' if n_look_towers == 1 else ''} a look"
    other = [f["reason"] for f in flags if f["code"] != "tower"]
    if other:
        s += "; block needs a look: " + "; ".join(other)
    elif not flags:
        s += "; nothing to check"
    return s + "."


def _card(value: str, key: str) -> str:
    return f'<div class="card"><div class="v">{value}</div><div class="k">{_esc(key)}</div></div>'


def _block_html(d: Mapping[str, Any], map_png: str | None, figures: list[str]) -> str:
    title = f"QA {d['zone'] + ' / ' if d['zone'] else ''}{d['block']}"
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{_esc(title)}</title>"
             f"<meta name='viewport' content='width=device-width,initial-scale=1'><style>{_CSS}</style></head><body><main>"]
    parts.append(f"<h1>Block {_esc(d['block'])}</h1><div class='sub'>zone {_esc(d['zone'] or '–')} · "
                 f"model {_esc(d['model'].get('name', '–'))} {_esc(d['model'].get('version', ''))} · "
                 f"page generated {_esc(d['generated_at'])}</div>")
    parts.append(f"<div class='summary {'ok' if d['status'] == 'ok' else 'look'}'>{_esc(d['summary'])}</div>")
    dens = d["density"] or {}
    cards = [_card(_fmt(d["n_towers"]), "towers found"),
             _card(_fmt(d["points"]), "points"),
             _card(_fmt(dens.get("density_median")), "median density (pts/m²)"),
             _card(_fmt(100 * d["ground_ratio"]) + " %" if d["ground_ratio"] is not None else "–", "ground points"),
             _card(_fmt(d["windows_passed_gate"]) + " / " + _fmt(d["windows_total"]), "windows gated / total"),
             _card(_fmt(d["tower_prob_mean"], 2), "mean tower probability")]
    if d["accuracy"]:
        a = d["accuracy"]
        cards += [_card(_fmt(a["recall"], 2), "tower recall vs labels"),
                  _card(_fmt(a["precision"], 2), "tower precision vs labels"),
                  _card(_fmt(a["point_iou"], 2), "point IoU vs labels")]
    parts.append(f"<div class='cards'>{''.join(cards)}</div>")
    if d["flags"]:
        parts.append("<h2>Needs a look</h2><ul class='warn'>" +
                     "".join(f"<li><span class='flag'>{_esc(f['code'].replace('_', ' '))}</span> {_esc(f['reason'])}</li>"
                             for f in d["flags"]) + "</ul>")

    parts.append("<h2>Towers</h2>")
    if map_png:
        parts.append(_figure(map_png, "Dashed: block bounds. Towers straddling the edge belong to the block "
                                      "that holds their centroid."))
    if d["towers"]:
        rows, classes = [], []
        for t in d["towers"]:
            rows.append([str(t["n"]), f"<code>{_esc(t['tower_id'])}</code>", _fmt(t["x"]), _fmt(t["y"]),
                         _fmt(t["height_m"]), _fmt(t["base_z"]), _fmt(t["n_points"]), _fmt(t["prob_mean"], 2),
                         _fmt(t["prob_max"], 2), _fmt(t.get("wire_support"), 2), _esc(t["blocks"]),
                         _fmt(t["edge_distance_m"]),
                         " ".join(f"<span class='flag'>{_esc(f)}</span>" for f in t["flags"]) or "<span class='ok'>ok</span>"])
            classes.append("look" if t["flags"] else "")
        parts.append(_table(["#", "tower id", "x (m)", "y (m)", "height (m)", "base z (m)", "points",
                             "mean prob", "max prob", "wire support", "blocks", "edge dist (m)", "check"], rows,
                            [True, False, True, True, True, True, True, True, True, True, False, True, False],
                            classes))
    else:
        parts.append("<p class='muted'>No towers in this block.</p>")

    if d["accuracy"]:
        a = d["accuracy"]
        parts.append("<h2>Accuracy against the input's class 15 labels</h2>")
        parts.append(_table(["measure", "value"], [
            ["labelled towers (centroid in block)", _fmt(a["towers_true"])],
            ["towers found / matched (≤ 5 m or overlapping)", f"{_fmt(a['tp'] + a['fp'])} / {_fmt(a['tp'])}"],
            ["tower precision", _fmt(a["precision"], 3)], ["tower recall", _fmt(a["recall"], 3)],
            ["tower F1", _fmt(a["f1"], 3)],
            ["points labelled tower / classified tower / both",
             f"{_fmt(a['points_true'])} / {_fmt(a['points_pred'])} / {_fmt(a['points_both'])}"],
            ["point IoU (tower)", _fmt(a["point_iou"], 3)]], [False, True]))

    parts.append("<h2>Points and ground</h2><div class='grid'><div>")
    parts.append(_table(["stage", "points"], [[_esc(k), _fmt(v)] for k, v in d["stage_counts"].items()],
                        [False, True]))
    ground_src = ", ".join(d["ground_sources"]) or "–"
    parts.append(_table(["ground", ""], [
        ["ground source", _esc(ground_src)],
        ["ground classified by towerpipe", _fmt(d["ground_classified"])],
        ["ground share of points", (_fmt(100 * d["ground_ratio"]) + " %") if d["ground_ratio"] is not None else "–"],
        ["block area", (_fmt(d["area_m2"] / 1e4, 2) + " ha") if d["area_m2"] else "–"],
        ["mean density", _fmt(dens.get("mean")) + " pts/m²"],
        ["median / 5th pct density (non-empty cells)",
         f"{_fmt(dens.get('density_median'))} / {_fmt(dens.get('density_p05'))} pts/m²"],
        ["empty cells", _fmt(dens.get("empty_cells_pct")) + " %"]], [False, True]))
    parts.append("</div>" + "".join(figures) + "</div>")

    parts.append("<h2>Windows and model</h2>")
    parts.append(_table(["", "value"], [
        ["tiles / prediction files", f"{_fmt(d['tiles'])} / {_fmt(d['pred_files'])}"],
        ["40 m windows in total", _fmt(d["windows_total"])],
        ["passed the classifier gate", _fmt(d["windows_passed_gate"]) +
         (f" ({_fmt(100 * d['gate_ratio'])} %)" if d["gate_ratio"] is not None else "")],
        ["segmented", _fmt(d["windows_segmented"])],
        ["model", _esc(" ".join(str(d["model"].get(k, "")) for k in ("name", "version", "feature_set")).strip() or "–")],
        ["model sha256", f"<code>{_esc(str(d['model'].get('sha256', '–'))[:16])}</code>"]], [False, True]))

    parts.append("<h2>Time and memory</h2>")
    if d["timings"]:
        total = sum(t["seconds"] or 0 for t in d["timings"] if t["stage"].find(":") < 0)
        rows = [[_esc(t["stage"]), _fmt(t["seconds"]), _fmt(t["max_rss_mb"], 0)] for t in d["timings"]]
        parts.append(_table(["stage", "wall time (s)", "peak memory (MB)"], rows, [False, True, True]))
        if total:
            parts.append(f"<p class='muted'>Jobs of this block (benchmarks): {_fmt(total)} s in total.</p>")
    else:
        parts.append("<p class='muted'>No timings recorded.</p>")

    parts.append("<h2>Warnings</h2>")
    parts.append("<ul class='warn'>" + "".join(f"<li>{_esc(w)}</li>" for w in d["warnings"]) + "</ul>"
                 if d["warnings"] else "<p class='muted'>None.</p>")
    if d["stats"]:
        parts.append("<h2>Other numbers</h2>")
        parts.append(_table(["name", "value"], [[_esc(k), _fmt(v) if not isinstance(v, (dict, list))
                                                 else f"<code>{_esc(json.dumps(v))}</code>"]
                                                for k, v in d["stats"].items()], [False, True]))
    parts.append("<footer>towerpipe QA · all numbers of this page are in the JSON next to it "
                 f"(<code>{_esc(Path(d['html']).with_suffix('.json').name)}</code>)</footer></main></body></html>")
    return "".join(parts)


# --------------------------------------------------------------------------- zone index
def zone_index(out_html: str | os.PathLike[str], block_jsons: Sequence[str | os.PathLike[str]], *,
               failures: Mapping[str, str] | None = None, zone: str = "",
               out_json: str | os.PathLike[str] | None = None,
               vanished: Sequence[Mapping[str, Any]] = ()) -> dict[str, Any]:
    """Write the zone's QA index: every block, totals, and the blocks that need a look.

    Parameters
    ----------
    out_html
        Destination page; links to the block pages are relative to it (each block
        page is expected next to its JSON).
    block_jsons
        JSON files written by :func:`block_report` (missing/unreadable ones are
        listed as failed).
    failures
        Block name → reason, for blocks whose jobs failed (no JSON).
    zone
        Zone name for the title.
    out_json
        Optional JSON with the index numbers.
    vanished
        Registered towers the run did not find again (``tower_id``, ``block``,
        ``centroid_x``, ``centroid_y``, ``height_m``, ``last_seen``, ``vanished_since``,
        ``review_status``; the zone's ``vanished_towers`` layer), listed under the blocks.

    Returns
    -------
    dict
        ``blocks`` (one dict per block: name, status ``ok``/``look``/``failed``,
        reasons …) and ``totals``.
    """
    out_html = Path(out_html)
    failures = dict(failures or {})
    blocks: list[dict[str, Any]] = []
    for p in block_jsons:
        p = Path(p)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            blocks.append({"block": p.stem, "status": "failed", "reasons": [f"QA JSON unreadable: {exc}"]})
            continue
        if d.get("block") in failures:
            continue
        href = os.path.relpath(p.parent / d.get("html", p.stem + ".html"), out_html.parent)
        blocks.append({"block": d.get("block", p.stem), "status": d.get("status", "look"), "href": href,
                       "reasons": [f["reason"] for f in d.get("flags", [])], "codes": [f["code"] for f in d.get("flags", [])],
                       "n_towers": d.get("n_towers", 0), "points": d.get("points"),
                       "density": (d.get("density") or {}).get("density_median"),
                       "ground_ratio": d.get("ground_ratio"), "ground_classified": d.get("ground_classified"),
                       "windows_total": d.get("windows_total"), "windows_passed_gate": d.get("windows_passed_gate"),
                       "tower_prob_mean": d.get("tower_prob_mean"), "accuracy": d.get("accuracy")})
    for b, reason in failures.items():
        blocks.append({"block": b, "status": "failed", "reasons": [str(reason)], "codes": ["failed"]})
    order = {"failed": 0, "look": 1, "ok": 2}
    blocks.sort(key=lambda b: (order.get(b["status"], 1), str(b["block"])))
    done = [b for b in blocks if b["status"] != "failed"]
    acc = [b["accuracy"] for b in done if b.get("accuracy")]
    totals = {
        "blocks": len(blocks), "failed": sum(b["status"] == "failed" for b in blocks),
        "look": sum(b["status"] == "look" for b in blocks), "ok": sum(b["status"] == "ok" for b in blocks),
        "towers": int(sum(b.get("n_towers") or 0 for b in done)),
        "points": int(sum(b.get("points") or 0 for b in done)),
        "windows_total": int(sum(b.get("windows_total") or 0 for b in done)),
        "windows_passed_gate": int(sum(b.get("windows_passed_gate") or 0 for b in done)),
    }
    if acc:
        tp, fp, fn = (sum(a[k] for a in acc) for k in ("tp", "fp", "fn"))
        totals["precision"] = tp / (tp + fp) if tp + fp else None
        totals["recall"] = tp / (tp + fn) if tp + fn else None
    s = f"{totals['towers']} tower{'s' if totals['towers'] != 1 else ''} found in {totals['blocks']} block" \
        f"{'s' if totals['blocks'] != 1 else ''}"
    if totals["failed"]:
        s += f"; {totals['failed']} failed"
    if totals["look"]:
        s += f"; {totals['look']} need{'s' if totals['look'] == 1 else ''} a look"
    if not totals["failed"] and not totals["look"]:
        s += "; nothing to check"
    totals["summary"] = s + "."
    totals["vanished_towers"] = len(vanished)
    doc = _jsonable({"zone": zone, "blocks": blocks, "totals": totals, "vanished_towers": list(vanished),
                     "generated_at": datetime.now(timezone.utc).replace(microsecond=0).isoformat()})
    if out_json is not None:
        write_text_atomic(out_json, json.dumps(doc, indent=1))
    write_text_atomic(out_html, _index_html(doc))
    return doc


def _index_html(d: Mapping[str, Any]) -> str:
    t = d["totals"]
    state = "fail" if t["failed"] else ("look" if t["look"] else "ok")
    title = f"QA zone {d['zone']}" if d["zone"] else "QA zone"
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{_esc(title)}</title>"
             f"<meta name='viewport' content='width=device-width,initial-scale=1'><style>{_CSS}</style></head><body><main>",
             f"<h1>{_esc(title)}</h1><div class='sub'>generated {_esc(d['generated_at'])}</div>",
             f"<div class='summary {state}'>{_esc(t['summary'])}</div>"]
    cards = [_card(_fmt(t["towers"]), "towers"), _card(_fmt(t["blocks"]), "blocks"),
             _card(_fmt(t["look"]), "need a look"), _card(_fmt(t["failed"]), "failed"),
             _card(_fmt(t["points"]), "points")]
    if t.get("recall") is not None or t.get("precision") is not None:
        cards += [_card(_fmt(t.get("recall"), 2), "tower recall vs labels"),
                  _card(_fmt(t.get("precision"), 2), "tower precision vs labels")]
    parts.append(f"<div class='cards'>{''.join(cards)}</div><h2>Blocks</h2>")
    rows, classes = [], []
    for b in d["blocks"]:
        name = f"<a href='{_esc(b['href'])}'>{_esc(b['block'])}</a>" if b.get("href") else _esc(b["block"])
        status = {"failed": "<span class='flag fail'>failed</span>", "look": "<span class='flag'>look</span>",
                  "ok": "<span class='ok'>ok</span>"}.get(b["status"], _esc(b["status"]))
        if b["status"] == "failed":
            rows.append([name, status, "–", "–", "–", "–", "–", "–", _esc("; ".join(b["reasons"]))])
        else:
            gr = b.get("ground_ratio")
            rows.append([name, status, _fmt(b.get("n_towers")), _fmt(b.get("points")), _fmt(b.get("density")),
                         (_fmt(100 * gr) + " %" + (" (classified)" if b.get("ground_classified") else ""))
                         if gr is not None else "–",
                         f"{_fmt(b.get('windows_passed_gate'))} / {_fmt(b.get('windows_total'))}",
                         _fmt(b.get("tower_prob_mean"), 2),
                         "<br>".join(_esc(r) for r in b["reasons"]) or "<span class='muted'>–</span>"])
        classes.append({"failed": "fail", "look": "look"}.get(b["status"], ""))
    rows.append(["total", "", _fmt(t["towers"]), _fmt(t["points"]), "", "",
                 f"{_fmt(t['windows_passed_gate'])} / {_fmt(t['windows_total'])}", "", ""])
    classes.append("total")
    parts.append(_table(["block", "status", "towers", "points", "density (pts/m²)", "ground",
                         "windows gated / total", "mean tower prob", "why it needs a look"], rows,
                        [False, False, True, True, True, True, True, True, False], classes))
    if d.get("vanished_towers"):
        parts.append("<h2>Towers no longer found</h2><p>Towers of the registry this run did not find again "
                     "(layer <code>vanished_towers</code> of towers.gpkg); a tower found again keeps its id.</p>")
        parts.append(_table(["tower id", "block", "x", "y", "height (m)", "last seen", "missing since", "review"],
                            [[f"<code>{_esc(v['tower_id'])}</code>", _esc(v["block"]), _fmt(v["centroid_x"]),
                              _fmt(v["centroid_y"]), _fmt(v["height_m"]), _esc(v["last_seen"]),
                              _esc(v["vanished_since"]), _esc(v["review_status"])] for v in d["vanished_towers"]],
                            [False, False, True, True, True, False, False, False]))
    parts.append("<footer>towerpipe QA index · click a block for its page</footer></main></body></html>")
    return "".join(parts)
