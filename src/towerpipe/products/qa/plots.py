"""The figures of the QA pages (matplotlib, Agg): maps, density, HAG, tower elevations, zone map.

Raster figures come back as ``data:image/png;base64,…`` URIs (the pages embed them, so
a page can be mailed or opened from a share); the zone map is inline SVG, so that its
blocks link to their pages.
"""

from __future__ import annotations

import base64
import io
import math
import os
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, NullFormatter

#: Colours shared by every figure (and by the pages' CSS).
TOWER_RED = "#e12d39"
TOWER_DARK = "#a50f15"
INK = "#1f2933"
STATUS_COLOURS = {"ok": "#c1eac5", "look": "#ffe08a", "failed": "#ff9b9b"}

#: Points drawn per elevation at most (the others are thinned evenly, towers never).
MAX_VIEW_POINTS = 60_000


def _figure(
    *grid: int,
    figsize: tuple[float, float] | None = None,
    margins: Mapping[str, float] | None = None,
    **kw: Any,
) -> tuple[Any, Any]:
    """A figure and its axes, as ``pyplot.subplots`` makes them, without pyplot: no figure
    manager or global state to close, whatever fails while drawing.

    ``margins`` (``Figure.subplots_adjust`` keywords) place the axes once: a layout engine or
    a tight bounding box measures every label in a draw of its own, which doubled the time
    of a QA job's figures."""
    fig = Figure(figsize=figsize)
    if margins:
        fig.subplots_adjust(**margins)
    return fig, fig.subplots(*grid, **kw)


def png(fig: Any, dpi: int = 100) -> str:
    """The figure as a PNG data URI (drawn once, at the margins :func:`_figure` set)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def svg(fig: Any) -> str:
    """The figure as an inline ``<svg>`` element that scales with its container."""
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    text = buf.getvalue()
    text = text[text.index("<svg") :]
    # inline in HTML the parser knows the SVG and XLink namespaces: no namespace URLs, and no
    # RDF metadata block, so the page names no address at all
    text = re.sub(r"<metadata>.*?</metadata>\s*", "", text, flags=re.S)
    text = re.sub(r'\s+xmlns(:\w+)?="[^"]*"', "", text)
    text = text.replace(' target="_blank"', "")  # a block's page opens in place of the index
    # keep the viewBox, drop the fixed size: the page's CSS sizes it
    return re.sub(r'<svg([^>]*?) width="[^"]*" height="[^"]*"', r'<svg\1 class="map"', text, count=1)


def _axes_style(ax: Any, labelsize: int = 8) -> None:
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=labelsize)


# --------------------------------------------------------------------------- rasters
def fill_nearest(grid: np.ndarray) -> np.ndarray:
    """NaN cells take the value of the nearest finite cell."""
    bad = ~np.isfinite(grid)
    if not bad.any() or bad.all():
        return np.where(bad, 0.0, grid)
    from scipy.ndimage import distance_transform_edt  # only for a grid with holes: a QA job seldom needs it

    idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
    return grid[tuple(idx)]


def max_z_grid(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, bounds: Sequence[float], max_cells: int = 700
) -> tuple[np.ndarray, float]:
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


def raster_grid(path: str | os.PathLike[str], max_cells: int = 900) -> tuple[np.ndarray, list[float], float]:
    """Band 1 of a DTM/DSM (decimated to <= ``max_cells`` per side), its bounds and cell size."""
    import rasterio

    with rasterio.open(path) as ds:
        f = max(1, int(math.ceil(max(ds.width, ds.height) / max_cells)))
        shape = (max(1, ds.height // f), max(1, ds.width // f))
        band = ds.read(1, out_shape=shape, masked=True).astype(np.float64)
        b = ds.bounds
        cell = abs(ds.transform.a) * ds.width / shape[1]
    return band.filled(np.nan), [b.left, b.bottom, b.right, b.top], cell


def hillshade(grid: np.ndarray, cell: float) -> np.ndarray:
    from matplotlib.colors import LightSource

    return LightSource(azdeg=315, altdeg=45).hillshade(fill_nearest(grid), vert_exag=1.0, dx=cell, dy=cell)


# --------------------------------------------------------------------------- block figures
def _near_far_edges(cx: float, cy: float, bounds: Sequence[float] | None, share: float = 0.1) -> tuple[bool, bool]:
    """Whether a point lies within ``share`` of the extent from the right and from the top edge of ``bounds``."""
    if bounds is None:
        return False, False
    xmin, ymin, xmax, ymax = bounds
    span = max(xmax - xmin, ymax - ymin, 1.0)
    return bool(cx > xmax - share * span), bool(cy > ymax - share * span)


def block_map(
    towers: Any,
    bounds: Sequence[float] | None,
    grid: np.ndarray | None,
    grid_bounds: Sequence[float] | None,
    cell: float,
    source: str,
) -> str:
    """The block's towers (numbered as in the table) over a hillshade."""
    fig, ax = _figure(figsize=(7.6, 7.2), margins={"left": 0.14, "right": 0.97, "bottom": 0.08, "top": 0.94})
    if grid is not None and np.isfinite(grid).any():
        gb = grid_bounds
        ax.imshow(hillshade(grid, cell), cmap="gray", extent=(gb[0], gb[2], gb[1], gb[3]), vmin=0, vmax=1)
        tint = ax.imshow(fill_nearest(grid), cmap="terrain", alpha=0.25, extent=(gb[0], gb[2], gb[1], gb[3]))
        fig.colorbar(tint, ax=ax, shrink=0.7, pad=0.02, label="elevation (m)")
    if bounds is not None:
        xmin, ymin, xmax, ymax = bounds
        ax.plot([xmin, xmax, xmax, xmin, xmin], [ymin, ymin, ymax, ymax, ymin], color=INK, lw=1.2, ls="--")
    for i, (geom, cx, cy) in enumerate(zip(towers.geometry, towers["centroid_x"], towers["centroid_y"]), 1):
        xs, ys = geom.exterior.xy
        ax.fill(xs, ys, facecolor=TOWER_RED, alpha=0.35, edgecolor=TOWER_DARK, lw=1.5)
        ax.plot(cx, cy, marker="^", color=TOWER_DARK, ms=9, mec="white", mew=1)
        right, top = _near_far_edges(cx, cy, bounds)
        ax.annotate(
            str(i),
            (cx, cy),
            # up and to the right of the tower, or toward the block's inside near its top and right
            # edges: a label beyond the axes lay over the figure's title
            xytext=(-6 if right else 6, -6 if top else 6),
            ha="right" if right else "left",
            va="top" if top else "bottom",
            textcoords="offset points",
            fontsize=11,
            weight="bold",
            color=INK,
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": TOWER_DARK, "alpha": 0.9},
        )
    _axes_style(ax)
    if bounds is not None:
        pad = 0.02 * max(bounds[2] - bounds[0], bounds[3] - bounds[1], 1.0)
        ax.set_xlim(bounds[0] - pad, bounds[2] + pad)
        ax.set_ylim(bounds[1] - pad, bounds[3] + pad)
    ax.set_xlabel("easting (m)")
    ax.set_ylabel("northing (m)")
    ax.set_title(f"Towers found (red, numbered as in the table) over a hillshade of {source}", fontsize=10)
    return png(fig)


def density_map(dens: np.ndarray, bounds: Sequence[float], cell: float) -> str:
    """Points per m² per cell (:func:`towerpipe.products.qa.metrics.density_grid`)."""
    xmin, ymin = bounds[0], bounds[1]
    ny, nx = dens.shape
    filled = dens[dens > 0]
    fig, ax = _figure(figsize=(5.4, 4.6), margins={"left": 0.16, "right": 0.97, "bottom": 0.08, "top": 0.93})
    vmax = max(1.0, float(np.percentile(filled, 98))) if filled.size else 1.0
    im = ax.imshow(dens, extent=(xmin, xmin + nx * cell, ymin, ymin + ny * cell), cmap="viridis", vmin=0, vmax=vmax)
    fig.colorbar(im, ax=ax, shrink=0.85, label="points / m²")
    _axes_style(ax, 7)
    ax.set_title(f"Point density ({cell:.3g} m cells)", fontsize=10)
    return png(fig)


def clipped_histogram(a: np.ndarray, rng: tuple[float, float], bins: int = 79) -> tuple[np.ndarray, np.ndarray]:
    """``np.histogram(np.clip(a, *rng), bins, range=rng)`` without the clipped copy of ``a``.

    Equal-width bins given as (count, range) take numpy's fast path (no per-point search,
    in blocks); the values below and above ``rng`` are counted in the first and last bin.
    """
    counts, edges = np.histogram(a, bins=bins, range=rng)
    counts[0] += np.count_nonzero(a < rng[0])
    counts[-1] += np.count_nonzero(a > rng[1])
    return counts, edges


def count_label(v: float, _pos: int | None = None) -> str:
    """A count as short plain text: 1, 10, 100, 1k, 10k, 100k, 1M."""
    for div, suffix in ((1e6, "M"), (1e3, "k")):
        if v >= div:
            return f"{v / div:g}{suffix}"
    return f"{v:g}"


def hag_histogram(hag: np.ndarray, tower: np.ndarray | None) -> str:
    """Histogram of heights above ground (log counts), the tower points' in red."""
    fig, ax = _figure(figsize=(5.4, 4.2), margins={"left": 0.14, "right": 0.97, "bottom": 0.12, "top": 0.92})
    tower = tower if tower is not None and len(tower) == len(hag) else None
    ok = np.isfinite(hag)
    if not ok.all():  # a copy only where the DTM has holes
        tower = tower[ok] if tower is not None else None
        hag = hag[ok]
    # the towers whole (a tower is a few hundred points over a million: above the 99.9th percentile)
    top = float(hag[tower].max()) if tower is not None and tower.any() else 0.0
    hi = max(10.0, top, float(np.percentile(hag, 99.9))) if hag.size else 10.0
    rng = (min(-2.0, float(hag.min()) if hag.size else -2.0), hi)
    counts, edges = clipped_histogram(hag, rng)
    ax.stairs(counts, edges, fill=True, color="#829ab1", label="all points")
    if tower is not None and tower.any():
        ax.stairs(
            clipped_histogram(hag[tower], rng)[0],
            edges,
            fill=True,
            color=TOWER_RED,
            alpha=0.8,
            label="classified tower (15)",
        )
    for b in (3.0, 8.0):
        ax.axvline(b, color="#616e7c", lw=0.8, ls=":")
    ax.set_yscale("log")
    # counts as plain text (1, 10, ..., 1k, 1M): the default 10^n labels set mathematical text,
    # whose fonts a QA job would load for this one figure
    ax.yaxis.set_major_formatter(FuncFormatter(count_label))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("height above ground (m)")
    ax.set_ylabel("points (log)")
    ax.legend(fontsize=8)
    ax.set_title("Height above ground (dotted: 3 m / 8 m sampling bands)", fontsize=10)
    return png(fig)


def principal_axis(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Unit vector of the longest horizontal extent of points (a tower's crossarms)."""
    xy = np.column_stack([x - x.mean(), y - y.mean()])
    if len(xy) < 3:
        return np.array([1.0, 0.0])
    w, v = np.linalg.eigh(xy.T @ xy)
    axis = v[:, int(np.argmax(w))]
    return axis if axis[0] >= 0 else -axis


def tower_elevations(hood: Mapping[str, np.ndarray], centre: Sequence[float], title: str) -> str:
    """Two elevations (side views) of a tower and the points around it.

    Parameters
    ----------
    hood
        ``x, y, z`` of the points around the tower and ``tower`` (bool: the tower's own
        points, as classified 15), e.g. from :func:`towerpipe.products.qa.neighbourhoods.tower_neighbourhoods`.
    centre
        The tower's footprint centroid.
    title
        Shown above the two views.

    The first view looks across the tower's crossarms (horizontal axis: along them, the
    principal axis of the tower's points), the second along them; conductors leaving the
    tower show in the first.
    """
    x, y, z, is_tower = (np.asarray(hood[k]) for k in ("x", "y", "z", "tower"))
    cx, cy = float(centre[0]), float(centre[1])
    axis = principal_axis(x[is_tower], y[is_tower]) if is_tower.sum() >= 3 else np.array([1.0, 0.0])
    u = (x - cx) * axis[0] + (y - cy) * axis[1]
    v = -(x - cx) * axis[1] + (y - cy) * axis[0]
    other = np.flatnonzero(~is_tower)
    if len(other) > MAX_VIEW_POINTS:
        other = other[np.linspace(0, len(other) - 1, MAX_VIEW_POINTS).astype(np.int64)]
    bearing = math.degrees(math.atan2(axis[0], axis[1])) % 180.0
    fig, axes = _figure(
        1,
        2,
        figsize=(10.0, 4.0),
        sharey=True,
        margins={"left": 0.07, "right": 0.99, "bottom": 0.13, "top": 0.88, "wspace": 0.05},
    )
    for ax, h, label in (
        (axes[0], u, f"along the crossarms (bearing {bearing:.0f}°), m"),
        (axes[1], v, f"across the crossarms (bearing {(bearing + 90) % 180:.0f}°), m"),
    ):
        ax.scatter(h[other], z[other], s=0.4, c="#9aa5b1", linewidths=0, rasterized=True)
        ax.scatter(h[is_tower], z[is_tower], s=2.0, c=TOWER_RED, linewidths=0, rasterized=True)
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=7)
        ax.set_xlabel(label, fontsize=8)
        ax.grid(True, lw=0.3, color="#d9e2ec")
    axes[0].set_ylabel("elevation z (m)", fontsize=8)
    fig.suptitle(title, fontsize=10)
    return png(fig, dpi=80)


# --------------------------------------------------------------------------- zone map
def zone_map(
    blocks: Sequence[Mapping[str, Any]], towers: Sequence[tuple[float, float]] = (), lines: Sequence[np.ndarray] = ()
) -> str:
    """The zone at a glance (inline SVG): blocks coloured by status and linked to their pages,
    towers, lines.

    Parameters
    ----------
    blocks
        ``block``, ``status`` (``ok`` / ``look`` / ``failed``), ``bounds`` (or None: not
        drawn) and ``href`` (or None) of each block.
    towers
        Tower centroids.
    lines
        ``(n, 2)`` vertex arrays of the lines between towers.
    """
    from matplotlib.patches import Patch, Rectangle

    fig, ax = _figure(figsize=(7.0, 6.0))
    drawn = [b for b in blocks if b.get("bounds")]
    for b in drawn:
        xmin, ymin, xmax, ymax = b["bounds"]
        rect = Rectangle(
            (xmin, ymin),
            xmax - xmin,
            ymax - ymin,
            facecolor=STATUS_COLOURS.get(b["status"], "#eee"),
            edgecolor=INK,
            lw=0.8,
            hatch="//" if b["status"] == "failed" else None,
        )
        if b.get("href"):
            rect.set_url(b["href"])
        ax.add_patch(rect)
        size = min(xmax - xmin, ymax - ymin)
        ax.text(
            (xmin + xmax) / 2,
            ymin + 0.06 * size,
            str(b["block"]),
            ha="center",
            va="bottom",
            fontsize=7,
            color=INK,
            url=b.get("href"),
        )
    for line in lines:
        ax.plot(line[:, 0], line[:, 1], color="#2680c2", lw=1.4, zorder=3)
    if len(towers):
        t = np.asarray(towers, dtype=float)
        ax.plot(t[:, 0], t[:, 1], ls="none", marker="^", color=TOWER_DARK, ms=7, mec="white", mew=0.8, zorder=4)
    if drawn:
        b = np.asarray([d["bounds"] for d in drawn], dtype=float)
        pad = 0.03 * max(b[:, 2].max() - b[:, 0].min(), b[:, 3].max() - b[:, 1].min(), 1.0)
        ax.set_xlim(b[:, 0].min() - pad, b[:, 2].max() + pad)
        ax.set_ylim(b[:, 1].min() - pad, b[:, 3].max() + pad)
    _axes_style(ax, 7)
    handles = [
        Patch(facecolor=STATUS_COLOURS[s], edgecolor=INK, hatch="//" if s == "failed" else None, label=lab)
        for s, lab in (("ok", "block: ok"), ("look", "block: needs a look"), ("failed", "block: failed"))
    ]
    handles.append(Line2D([], [], ls="none", marker="^", color=TOWER_DARK, mec="white", label="tower"))
    if len(lines):
        handles.append(Line2D([], [], color="#2680c2", lw=1.4, label="line"))
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.set_title("Zone overview: click a block for its page", fontsize=10)
    return svg(fig)
