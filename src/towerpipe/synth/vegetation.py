"""Vegetation: forests, shrubs, scattered and tall isolated trees, rasterised per
block into a canopy model (top / crown base above ground, tree id) that the pulse
model reads to produce multiple returns through canopies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from towerpipe.synth.params import SceneParams
from towerpipe.synth.rng import derive


@dataclass
class Trees:
    """All trees of a zone (one row per tree).

    Attributes
    ----------
    x, y
        Stem position.
    h
        Height (m).
    r
        Crown radius (m).
    base
        Crown base height above ground (m).
    kind
        0 broadleaf (dome crown), 1 conifer (cone), 2 shrub.
    """

    x: np.ndarray
    y: np.ndarray
    h: np.ndarray
    r: np.ndarray
    base: np.ndarray
    kind: np.ndarray

    def subset(self, m: np.ndarray) -> Trees:
        """Trees selected by a mask / index."""
        return Trees(*(getattr(self, k)[m] for k in ("x", "y", "h", "r", "base", "kind")))

    def __len__(self) -> int:
        return len(self.x)


def noise_field(seed: int, key: str, scale: float, n: int = 24):
    """A smooth random field in [-1, 1]-ish of correlation length ``scale`` (callable)."""
    rng = derive(seed, "field", key)
    lam = scale * np.exp(rng.uniform(-0.7, 0.7, n))
    ang = rng.uniform(0, 2 * np.pi, n)
    kx, ky = np.cos(ang) * 2 * np.pi / lam, np.sin(ang) * 2 * np.pi / lam
    ph = rng.uniform(0, 2 * np.pi, n)
    amp = np.sqrt(2.0 / n)

    def f(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        out = np.zeros(np.broadcast(x, y).shape)
        for i in range(n):
            out += np.cos(kx[i] * x + ky[i] * y + ph[i])
        return out * amp

    return f


def make_trees(seed: int, bounds, params: SceneParams) -> Trees:
    """Draw every tree and shrub of the zone."""
    xmin, ymin, xmax, ymax = bounds
    area = (xmax - xmin) * (ymax - ymin)
    forest = noise_field(seed, "forest", params.forest_scale)
    rng = derive(seed, "forest-threshold")
    probe = forest(rng.uniform(xmin, xmax, 4000), rng.uniform(ymin, ymax, 4000))
    thr = np.quantile(probe, 1 - params.forest_cover) if params.forest_cover > 0 else np.inf
    parts = []
    # forest trees
    r = derive(seed, "trees", "forest")
    n = r.poisson(params.forest_tree_density * area)
    x, y = r.uniform(xmin, xmax, n), r.uniform(ymin, ymax, n)
    m = forest(x, y) > thr
    x, y = x[m], y[m]
    k = len(x)
    tall = r.random(k) < params.tall_tree_share
    h = np.where(tall, r.uniform(*params.tall_height, k), r.uniform(*params.forest_height, k))
    kind = np.where(tall & (r.random(k) < 0.7), 1, 0)
    ratio = r.uniform(*params.forest_crown_ratio, k) * np.where(kind == 1, 0.6, 1.0)
    parts.append((x, y, h, np.clip(h * ratio, 0.8, 7.0), h * r.uniform(0.15, 0.45, k), kind))
    # shrubs (everywhere, denser in forest)
    r = derive(seed, "trees", "shrubs")
    n = r.poisson(params.shrub_density * area)
    x, y = r.uniform(xmin, xmax, n), r.uniform(ymin, ymax, n)
    keep = r.random(n) < np.where(forest(x, y) > thr, 1.0, 0.35)
    x, y = x[keep], y[keep]
    k = len(x)
    h = r.uniform(*params.shrub_height, k)
    parts.append((x, y, h, np.clip(h * r.uniform(0.35, 0.7, k), 0.3, 1.8), h * r.uniform(0.0, 0.2, k), np.full(k, 2)))
    # scattered trees in open land
    r = derive(seed, "trees", "scattered")
    n = r.poisson(params.scattered_trees * area / 1e6)
    x, y = r.uniform(xmin, xmax, n), r.uniform(ymin, ymax, n)
    h = r.uniform(4.0, 14.0, n)
    kind = (r.random(n) < 0.3).astype(int)
    parts.append((x, y, h, np.clip(h * r.uniform(0.25, 0.45, n), 1.0, 6.5), h * r.uniform(0.2, 0.45, n), kind))
    # tall isolated trees (poplars, pines): hard negatives for "tall thin things"
    r = derive(seed, "trees", "isolated")
    n = r.poisson(params.isolated_tall_trees * area / 1e6)
    x, y = r.uniform(xmin, xmax, n), r.uniform(ymin, ymax, n)
    h = r.uniform(18.0, 30.0, n)
    kind = (r.random(n) < 0.5).astype(int)
    parts.append((x, y, h, h * r.uniform(0.09, 0.2, n), h * r.uniform(0.15, 0.4, n), kind))
    cols = [np.concatenate([p[i] for p in parts]) for i in range(6)]
    return Trees(cols[0], cols[1], cols[2], cols[3], cols[4], cols[5].astype(np.int8))


@dataclass
class Canopy:
    """Canopy rasters of one block.

    Attributes
    ----------
    x0, y0, res, nx, ny
        Grid geometry (cell (0, 0) has its lower-left corner at (x0, y0)).
    top, base
        Canopy top and crown base above ground (m), 0 where no vegetation.
    tree
        Index of the visible tree (into the block's :class:`Trees`), -1 where none.
    """

    x0: float
    y0: float
    res: float
    nx: int
    ny: int
    top: np.ndarray
    base: np.ndarray
    tree: np.ndarray

    def cell(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat cell index of points (clamped to the grid)."""
        ix = np.clip(((x - self.x0) / self.res).astype(np.int64), 0, self.nx - 1)
        iy = np.clip(((y - self.y0) / self.res).astype(np.int64), 0, self.ny - 1)
        return iy * self.nx + ix


def rasterize(trees: Trees, bounds, res: float, rng: np.random.Generator) -> Canopy:
    """Canopy model of ``trees`` over ``bounds`` (the tallest crown surface wins).

    Crowns are domes (broadleaf, shrubs) or cones (conifers); the crown surface gets
    a small roughness.
    """
    xmin, ymin, xmax, ymax = bounds
    nx = int(np.ceil((xmax - xmin) / res))
    ny = int(np.ceil((ymax - ymin) / res))
    top = np.zeros(nx * ny, np.float32)
    base = np.zeros(nx * ny, np.float32)
    tree = np.full(nx * ny, -1, np.int32)
    rc = np.ceil(trees.r / res).astype(np.int64)
    cells, vals, bases, ids = [], [], [], []
    for k in np.unique(rc):
        sel = np.flatnonzero(rc == k)
        off = np.arange(-k, k + 1)
        ox, oy = np.meshgrid(off, off)
        ox, oy = ox.ravel(), oy.ravel()
        cx = np.floor((trees.x[sel] - xmin) / res).astype(np.int64)
        cy = np.floor((trees.y[sel] - ymin) / res).astype(np.int64)
        gx = cx[:, None] + ox[None, :]
        gy = cy[:, None] + oy[None, :]
        px = xmin + (gx + 0.5) * res - trees.x[sel, None]
        py = ymin + (gy + 0.5) * res - trees.y[sel, None]
        d = np.hypot(px, py) / trees.r[sel, None]
        ok = (d <= 1) & (gx >= 0) & (gx < nx) & (gy >= 0) & (gy < ny)
        h = trees.h[sel, None]
        b = trees.base[sel, None]
        cone = trees.kind[sel, None] == 1
        prof = np.where(cone, 1 - d, np.sqrt(np.clip(1 - d**2, 0, 1)))
        z = b + (h - b) * prof
        ti = np.broadcast_to(sel[:, None], d.shape)
        cells.append((gy * nx + gx)[ok])
        vals.append(z[ok])
        bases.append(np.broadcast_to(b, d.shape)[ok])
        ids.append(ti[ok])
    if cells:
        c = np.concatenate(cells)
        v = np.concatenate(vals).astype(np.float32)
        v += rng.normal(0, 0.15, v.size).astype(np.float32) * (v > 1)
        o = np.argsort(v, kind="stable")  # ascending: the tallest is written last
        top[c[o]] = v[o]
        base[c[o]] = np.concatenate(bases)[o]
        tree[c[o]] = np.concatenate(ids)[o]
    top = np.maximum(top, 0)
    return Canopy(xmin, ymin, res, nx, ny, top, base, tree)
