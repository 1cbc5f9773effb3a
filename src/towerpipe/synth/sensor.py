"""Airborne scanner model: parallel flight strips with an oscillating-mirror zig-zag.

The aircraft flies straight strips at ``flight_height`` with a heading; the mirror
sweeps the beam across track between ±``half_fov_deg`` at ``scan_rate_hz`` sweeps
pairs per second, so pulses fall on slanted, zig-zagging scan lines. Neighbouring
strips overlap by ``strip_overlap`` (double density there). Pulses are generated
sweep by sweep only for the part of the swath over a block, so no pulse is wasted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from towerpipe.synth.params import SceneParams
from towerpipe.synth.rng import derive

#: GPS time (adjusted standard) of the first strip.
GPS_T0 = 3.3e8


@dataclass
class FlightPlan:
    """Strips of a zone.

    Attributes
    ----------
    cx, cy
        Reference point of the along/across frame (zone centre).
    heading
        Flight direction (radians, counter-clockwise from +x).
    strip_v
        Across-track coordinate of each strip's axis.
    height
        Flight height above the ground (m).
    half_fov
        Half field of view (radians).
    speed, scan_rate, prf
        Aircraft speed (m/s), mirror sweep pairs per second, pulses per second.
    """

    cx: float
    cy: float
    heading: float
    strip_v: np.ndarray
    height: float
    half_fov: float
    speed: float
    scan_rate: float
    prf: float

    @property
    def half_swath(self) -> float:
        """Half the swath width (m)."""
        return self.height * np.tan(self.half_fov)

    def to_uv(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Along-track (u) and across-track (v) coordinates."""
        c, s = np.cos(self.heading), np.sin(self.heading)
        dx, dy = x - self.cx, y - self.cy
        return dx * c + dy * s, -dx * s + dy * c

    def to_xy(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`to_uv`."""
        c, s = np.cos(self.heading), np.sin(self.heading)
        return self.cx + u * c - v * s, self.cy + u * s + v * c

    def coverage(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Number of strips that see each (x, y)."""
        _, v = self.to_uv(np.asarray(x, float), np.asarray(y, float))
        d = np.abs(v[:, None] - self.strip_v[None, :])
        return (d <= self.half_swath).sum(axis=1)

    def attributes(
        self, x: np.ndarray, y: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Strip index, scan angle (degrees) and GPS time of returns at (x, y).

        Where strips overlap, one of the covering strips is drawn at random.
        """
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        u, v = self.to_uv(x, y)
        d = v[:, None] - self.strip_v[None, :]
        cover = np.abs(d) <= self.half_swath
        score = rng.random(cover.shape) + cover  # covering strips score > 1
        j = np.argmax(score, axis=1)
        dv = d[np.arange(len(x)), j]
        ang = np.degrees(np.arctan2(dv, self.height))
        t = GPS_T0 + j * 900.0 + u / self.speed
        return j.astype(np.int64), ang, t


def make_flight_plan(
    seed: int, bounds: tuple[float, float, float, float], params: SceneParams, density: float
) -> FlightPlan:
    """Lay strips over a zone so that single coverage gives ``density`` pulses/m²."""
    rng = derive(seed, "flight")
    xmin, ymin, xmax, ymax = bounds
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    heading = np.radians(params.heading_deg) if params.heading_deg is not None else rng.uniform(0, np.pi)
    half_fov = np.radians(params.half_fov_deg)
    hs = params.flight_height * np.tan(half_fov)
    spacing = 2 * hs * (1 - params.strip_overlap)
    plan = FlightPlan(
        cx, cy, heading, np.zeros(0), params.flight_height, half_fov, params.aircraft_speed, params.scan_rate_hz, 0.0
    )
    cu, cv = plan.to_uv(np.array([xmin, xmax, xmax, xmin]), np.array([ymin, ymin, ymax, ymax]))
    vmin, vmax = cv.min(), cv.max()
    start = vmin - rng.uniform(0, spacing)
    n = int(np.ceil((vmax + hs - start) / spacing)) + 1
    sv = start + spacing * np.arange(n)
    sv = sv[(sv - hs < vmax) & (sv + hs > vmin)]
    plan.strip_v = sv
    plan.prf = density * params.aircraft_speed * 2 * hs
    return plan


def pulses(
    plan: FlightPlan,
    bounds: tuple[float, float, float, float],
    rng: np.random.Generator,
    jitter: float = 0.05,
    thin: float = 1.0,
) -> dict[str, np.ndarray]:
    """Footprints of all pulses of all strips that land inside ``bounds``.

    ``thin`` < 1 keeps only that share of pulses at random (lower effective pulse rate).

    Returns
    -------
    dict
        ``x``, ``y`` (float64), ``strip`` (int64), ``scan_angle`` (degrees, float32),
        ``gps_time`` (float64).
    """
    xmin, ymin, xmax, ymax = bounds
    cu, cv = plan.to_uv(np.array([xmin, xmax, xmax, xmin]), np.array([ymin, ymin, ymax, ymax]))
    umin, umax, vmin, vmax = cu.min() - 1, cu.max() + 1, cv.min() - 1, cv.max() + 1
    per_sweep = plan.prf / (2 * plan.scan_rate)  # pulses in one mirror sweep
    dtheta = 2 * plan.half_fov / per_sweep
    sweep_dt = 1.0 / (2 * plan.scan_rate)
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("x", "y", "strip", "scan_angle", "gps_time")}
    for j, sv in enumerate(plan.strip_v):
        lo = np.arctan((max(vmin - sv, -plan.half_swath)) / plan.height)
        hi = np.arctan((min(vmax - sv, plan.half_swath)) / plan.height)
        if hi <= lo:
            continue
        i0 = int(np.floor((lo + plan.half_fov) / dtheta))
        i1 = int(np.ceil((hi + plan.half_fov) / dtheta))
        m0 = int(np.floor(umin / plan.speed / sweep_dt)) - 1
        m1 = int(np.ceil(umax / plan.speed / sweep_dt)) + 1
        m = np.arange(m0, m1 + 1)
        i = np.arange(i0, i1 + 1)
        # sweep m runs left->right when even, right->left when odd
        odd = (m % 2 == 1)[:, None]
        ii = np.where(odd, i[::-1][None, :], i[None, :])  # pulses in firing order
        pos = np.where(odd, per_sweep - ii, ii)
        t = m[:, None] * sweep_dt + pos / plan.prf
        theta = (-plan.half_fov + ii * dtheta).ravel()
        t = t.ravel()
        if thin < 1.0:
            k = rng.random(t.size) < thin
            t, theta = t[k], theta[k]
        u = t * plan.speed
        v = sv + plan.height * np.tan(theta)
        u = u + rng.normal(0, jitter, u.size)
        v = v + rng.normal(0, jitter, v.size)
        x, y = plan.to_xy(u, v)
        keep = (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)
        out["x"].append(x[keep])
        out["y"].append(y[keep])
        out["strip"].append(np.full(int(keep.sum()), j, np.int64))
        out["scan_angle"].append(np.degrees(theta[keep]).astype(np.float32))
        out["gps_time"].append(GPS_T0 + j * 900.0 + t[keep])
    return {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in out.items()}
