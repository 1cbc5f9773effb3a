"""Buildings (villages and scattered farms; flat and gable roofs, 3-30 m) and roads.

Roofs are rasterised per block (absolute roof elevation, building index) for the
pulse model; walls are sampled as vertical surfaces (few returns, airborne view).
Roads are polylines with a width, rasterised into a mask of class 11 ground.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from towerpipe.synth.params import SceneParams
from towerpipe.synth.rng import derive


@dataclass
class Buildings:
    """All buildings of a zone.

    Attributes
    ----------
    x, y, length, width, rot
        Centre, half... full length (along the ridge) and width, rotation (rad).
    h
        Eave height above ``base_z`` (m).
    ridge
        Extra ridge height of gable roofs (0 for flat roofs).
    base_z
        Lowest terrain elevation under the footprint.
    roof
        Roof material index (0 terracotta, 1 grey, 2 dark, 3 light flat).
    """

    x: np.ndarray
    y: np.ndarray
    length: np.ndarray
    width: np.ndarray
    rot: np.ndarray
    h: np.ndarray
    ridge: np.ndarray
    base_z: np.ndarray
    roof: np.ndarray

    def subset(self, m) -> Buildings:
        """Buildings selected by a mask / index."""
        return Buildings(
            *(getattr(self, k)[m] for k in ("x", "y", "length", "width", "rot", "h", "ridge", "base_z", "roof"))
        )

    def __len__(self) -> int:
        return len(self.x)

    def corners(self) -> np.ndarray:
        """(n, 4, 2) footprint corners."""
        c, s = np.cos(self.rot), np.sin(self.rot)
        a = np.array([1, -1, -1, 1])[None, :] * (self.length / 2)[:, None]
        b = np.array([1, 1, -1, -1])[None, :] * (self.width / 2)[:, None]
        return np.stack(
            [self.x[:, None] + a * c[:, None] - b * s[:, None], self.y[:, None] + a * s[:, None] + b * c[:, None]],
            axis=2,
        )


def make_roads(seed: int, bounds, params: SceneParams) -> list[tuple[np.ndarray, float]]:
    """Road polylines (vertices, width) crossing the zone."""
    rng = derive(seed, "roads")
    xmin, ymin, xmax, ymax = bounds
    area = (xmax - xmin) * (ymax - ymin) / 1e6
    n = int(rng.poisson(params.roads * area))
    diag = np.hypot(xmax - xmin, ymax - ymin)
    out = []
    for _ in range(n):
        p = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
        head = rng.uniform(0, 2 * np.pi)
        k = int(rng.integers(2, 6))
        steps = rng.uniform(0.3, 0.8, k) * diag
        heads = head + np.cumsum(rng.normal(0, 0.35, k))
        v = np.vstack([[0, 0], np.cumsum(np.c_[np.cos(heads), np.sin(heads)] * steps[:, None], axis=0)])
        v = v - v[k // 2] + p
        out.append((v, float(rng.uniform(*params.road_width))))
    return out


def make_buildings(seed: int, bounds, params: SceneParams, terrain_z, avoid) -> Buildings:
    """Draw villages and scattered buildings.

    Parameters
    ----------
    avoid
        Callable (x, y, radius) -> bool mask of positions to drop (roads, towers).
    """
    rng = derive(seed, "buildings")
    xmin, ymin, xmax, ymax = bounds
    area = (xmax - xmin) * (ymax - ymin) / 1e6
    xs, ys, rots = [], [], []
    for _ in range(int(rng.poisson(params.villages * area))):
        cx, cy = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
        n = int(rng.integers(*params.village_buildings))
        rad = rng.uniform(50, 140)
        xs.append(cx + rng.normal(0, rad / 2, n))
        ys.append(cy + rng.normal(0, rad / 2, n))
        rots.append(rng.uniform(0, np.pi) + rng.normal(0, 0.15, n))
    n = int(rng.poisson(params.scattered_buildings * area))
    xs.append(rng.uniform(xmin, xmax, n))
    ys.append(rng.uniform(ymin, ymax, n))
    rots.append(rng.uniform(0, np.pi, n))
    x, y, rot = np.concatenate(xs), np.concatenate(ys), np.concatenate(rots)
    k = len(x)
    length = rng.uniform(9, 35, k)
    width = np.minimum(length, rng.uniform(7, 18, k))
    tall = rng.random(k) < params.tall_building_share
    h = np.where(tall, rng.uniform(14, 30, k), rng.uniform(*params.building_height, k))
    flat = (rng.random(k) < params.flat_roof_share) | tall
    ridge = np.where(flat, 0.0, width * rng.uniform(0.15, 0.35, k))
    roof = np.where(flat, rng.choice([1, 3], k), rng.choice([0, 0, 1, 2], k))
    rad = np.hypot(length, width) / 2
    inside = (x - rad > xmin) & (x + rad < xmax) & (y - rad > ymin) & (y + rad < ymax)
    keep = inside & ~avoid(x, y, rad)
    # drop overlapping buildings (keep the first): coarse test on circumscribed circles
    idx = np.flatnonzero(keep)
    if len(idx) > 1:
        d = np.hypot(x[idx, None] - x[None, idx], y[idx, None] - y[None, idx])
        clash = np.triu(d < 0.8 * (rad[idx, None] + rad[None, idx]), 1)
        bad = np.zeros(len(idx), bool)
        for i in range(len(idx)):  # loop over buildings (few hundred), not points
            if not bad[i]:
                bad |= clash[i] & ~bad
        keep[idx[bad]] = False
    b = Buildings(x, y, length, width, rot, h, ridge, np.zeros(k), roof.astype(np.int8)).subset(keep)
    cz = terrain_z(b.corners()[..., 0].ravel(), b.corners()[..., 1].ravel()).reshape(-1, 4)
    b.base_z = cz.min(axis=1)
    return b


def rasterize_roofs(b: Buildings, x0: float, y0: float, res: float, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """Roof elevation (NaN where no roof) and building index per cell (flat arrays)."""
    roof = np.full(nx * ny, np.nan, np.float64)
    bid = np.full(nx * ny, -1, np.int32)
    if not len(b):
        return roof, bid
    corners = b.corners()
    for i in range(len(b)):  # loop over buildings, vectorised over cells
        cx0, cy0 = corners[i].min(axis=0)
        cx1, cy1 = corners[i].max(axis=0)
        ix = np.arange(max(0, int((cx0 - x0) / res)), min(nx, int((cx1 - x0) / res) + 1))
        iy = np.arange(max(0, int((cy0 - y0) / res)), min(ny, int((cy1 - y0) / res) + 1))
        if not len(ix) or not len(iy):
            continue
        gx, gy = np.meshgrid(ix, iy)
        px = x0 + (gx + 0.5) * res - b.x[i]
        py = y0 + (gy + 0.5) * res - b.y[i]
        c, s = np.cos(b.rot[i]), np.sin(b.rot[i])
        a = px * c + py * s
        w = -px * s + py * c
        ok = (np.abs(a) <= b.length[i] / 2) & (np.abs(w) <= b.width[i] / 2)
        z = b.base_z[i] + b.h[i] + b.ridge[i] * (1 - np.abs(w) / (b.width[i] / 2))
        flat = (gy * nx + gx)[ok]
        roof[flat] = np.fmax(roof[flat], z[ok])
        bid[flat] = i
    return roof, bid


def sample_walls(
    b: Buildings, density: float, vertical_factor: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Returns on building walls (few: airborne view), with their building index."""
    if not len(b):
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    c = b.corners()
    a = c
    bb = np.roll(c, -1, axis=1)
    wl = np.hypot(*(bb - a).transpose(2, 0, 1))  # (n, 4)
    lam = density * vertical_factor * 0.5 * wl * b.h[:, None]
    n = rng.poisson(lam).ravel()
    wi = np.repeat(np.arange(n.size), n)
    bi, si = wi // 4, wi % 4
    t = rng.random(wi.size)
    p = a[bi, si] + t[:, None] * (bb[bi, si] - a[bi, si])
    z = b.base_z[bi] + rng.random(wi.size) ** 0.7 * b.h[bi]
    return np.c_[p, z], bi


def rasterize_roads(roads, x0: float, y0: float, res: float, nx: int, ny: int) -> np.ndarray:
    """Boolean road mask per cell (flat array)."""
    mask = np.zeros(nx * ny, bool)
    for verts, width in roads:
        for a, b in zip(verts[:-1], verts[1:]):
            lo = np.minimum(a, b) - width
            hi = np.maximum(a, b) + width
            ix = np.arange(max(0, int((lo[0] - x0) / res)), min(nx, int((hi[0] - x0) / res) + 1))
            iy = np.arange(max(0, int((lo[1] - y0) / res)), min(ny, int((hi[1] - y0) / res) + 1))
            if not len(ix) or not len(iy):
                continue
            gx, gy = np.meshgrid(ix, iy)
            px = x0 + (gx + 0.5) * res
            py = y0 + (gy + 0.5) * res
            d = b - a
            t = np.clip(((px - a[0]) * d[0] + (py - a[1]) * d[1]) / max(d @ d, 1e-9), 0, 1)
            dist = np.hypot(px - a[0] - t * d[0], py - a[1] - t * d[1])
            mask[(gy * nx + gx)[dist <= width / 2]] = True
    return mask
