"""Smooth random terrain (sum of random Fourier modes) on a grid, bilinear lookup.

The terrain is the generator's ground truth: :meth:`Terrain.z` is the exact
surface on which ground points lie, so HAG = z - ``Terrain.z(x, y)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from towerpipe.synth.params import SceneParams
from towerpipe.synth.rng import derive


@dataclass
class Terrain:
    """A terrain grid with bilinear interpolation.

    Attributes
    ----------
    x0, y0
        Coordinates of grid node (0, 0).
    res
        Node spacing (m).
    grid
        Elevation (m above sea) of the nodes, shape (ny, nx).
    """

    x0: float
    y0: float
    res: float
    grid: np.ndarray

    def z(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Elevation at (x, y) by bilinear interpolation (clamped at the border)."""
        ny, nx = self.grid.shape
        fx = np.clip((np.asarray(x, dtype=np.float64) - self.x0) / self.res, 0, nx - 1.000001)
        fy = np.clip((np.asarray(y, dtype=np.float64) - self.y0) / self.res, 0, ny - 1.000001)
        ix = fx.astype(np.int64)
        iy = fy.astype(np.int64)
        tx = fx - ix
        ty = fy - iy
        g = self.grid
        i0 = iy * nx + ix
        flat = g.ravel()
        z00 = flat[i0]
        z10 = flat[i0 + 1]
        z01 = flat[i0 + nx]
        z11 = flat[i0 + nx + 1]
        return (z00 * (1 - tx) + z10 * tx) * (1 - ty) + (z01 * (1 - tx) + z11 * tx) * ty

    def slope_deg(self) -> np.ndarray:
        """Slope (degrees) at every node."""
        gy, gx = np.gradient(self.grid, self.res)
        return np.degrees(np.arctan(np.hypot(gx, gy)))

    def save(self, path: str | Path) -> None:
        """Write the grid to an ``.npz`` file."""
        np.savez_compressed(path, x0=self.x0, y0=self.y0, res=self.res, grid=self.grid.astype(np.float32))

    @classmethod
    def load(cls, path: str | Path) -> Terrain:
        """Read a grid written by :meth:`save`."""
        d = np.load(path)
        return cls(float(d["x0"]), float(d["y0"]), float(d["res"]), d["grid"].astype(np.float64))


def make_terrain(
    seed: int, bounds: tuple[float, float, float, float], params: SceneParams, margin: float = 150.0
) -> Terrain:
    """Build a random terrain covering ``bounds`` (+ margin).

    A sum of 48 cosine modes with a red (1/k²) spectrum between the wavelengths of
    ``params.terrain_wavelength``, rescaled so that the 99.5th percentile of the
    slope equals ``params.max_slope_deg``; the mean elevation is drawn from
    ``params.base_elevation``.
    """
    rng = derive(seed, "terrain")
    xmin, ymin, xmax, ymax = bounds
    res = params.terrain_res
    x0, y0 = xmin - margin, ymin - margin
    nx = int(np.ceil((xmax + margin - x0) / res)) + 1
    ny = int(np.ceil((ymax + margin - y0) / res)) + 1
    lo, hi = params.terrain_wavelength
    n = 48
    lam = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
    ang = rng.uniform(0, 2 * np.pi, n)
    kx = np.cos(ang) * 2 * np.pi / lam
    ky = np.sin(ang) * 2 * np.pi / lam
    amp = lam**1.0 * rng.rayleigh(1.0, n)  # slope spectrum ~ flat-ish per mode
    ph = rng.uniform(0, 2 * np.pi, n)
    # separable evaluation: cos(kx x + ky y + ph) = Re(e^{i kx x} e^{i ky y} e^{i ph})
    xs = np.arange(nx) * res + (x0 - xmin)
    ys = np.arange(ny) * res + (y0 - ymin)
    ex = np.exp(1j * np.outer(kx, xs))  # (n, nx)
    ey = np.exp(1j * np.outer(ky, ys))  # (n, ny)
    grid = np.real((ey * (amp * np.exp(1j * ph))[:, None]).T @ ex)  # (ny, nx)
    t = Terrain(x0, y0, res, grid)
    s = np.tan(np.radians(t.slope_deg()))
    target = np.tan(np.radians(params.max_slope_deg * rng.uniform(0.75, 1.0)))
    scale = target / max(np.percentile(s, 99.5), 1e-9)
    grid = grid * scale
    base = rng.uniform(*params.base_elevation)
    grid = grid - grid.mean() + base
    grid = np.maximum(grid, 1.0)
    return Terrain(x0, y0, res, grid)
