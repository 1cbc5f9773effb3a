"""Geometric primitives seen by an airborne scanner: members (segments) and patches.

Thin 3-D structures (lattice members, poles, tubes, wires) are sets of segments
with a width; horizontal surfaces on them (nacelle tops, chimney tops, counter
weights) are rectangular patches. :func:`sample_segments` draws returns on them
with the expected count an airborne scanner gets: local pulse density × length ×
effective width × (horizontal share + ``vertical_factor`` × vertical share).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Primitives:
    """A bag of segments and patches in world coordinates.

    Attributes
    ----------
    seg
        (M, 2, 3) segment end points.
    width
        (M,) member width / tube diameter (m).
    tube
        (M,) True where returns lie on the surface of a tube of that diameter.
    patch
        (P, 6) horizontal rectangles: cx, cy, z, half-length, half-width, rotation.
    """

    seg: np.ndarray
    width: np.ndarray
    tube: np.ndarray
    patch: np.ndarray

    @classmethod
    def empty(cls) -> Primitives:
        """No primitive."""
        return cls(np.zeros((0, 2, 3)), np.zeros(0), np.zeros(0, bool), np.zeros((0, 6)))

    @classmethod
    def concat(cls, items: list[Primitives]) -> Primitives:
        """Concatenate several bags."""
        if not items:
            return cls.empty()
        return cls(
            np.concatenate([p.seg for p in items]),
            np.concatenate([p.width for p in items]),
            np.concatenate([p.tube for p in items]),
            np.concatenate([p.patch for p in items]),
        )

    def transformed(self, x: float, y: float, z: float, rot: float) -> Primitives:
        """Rotate about z by ``rot`` (radians) and translate by (x, y, z)."""
        c, s = np.cos(rot), np.sin(rot)
        seg = self.seg.copy()
        sx, sy = seg[..., 0].copy(), seg[..., 1].copy()
        seg[..., 0] = x + c * sx - s * sy
        seg[..., 1] = y + s * sx + c * sy
        seg[..., 2] += z
        p = self.patch.copy()
        px, py = p[:, 0].copy(), p[:, 1].copy()
        p[:, 0] = x + c * px - s * py
        p[:, 1] = y + s * px + c * py
        p[:, 2] += z
        p[:, 5] += rot
        return Primitives(seg, self.width.copy(), self.tube.copy(), p)

    def xy_points(self) -> np.ndarray:
        """All end points and patch corners projected on xy (K, 2) (for outlines)."""
        pts = [self.seg.reshape(-1, 3)[:, :2]]
        if len(self.patch):
            p = self.patch
            for a, b in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                c, s = np.cos(p[:, 5]), np.sin(p[:, 5])
                pts.append(
                    np.c_[p[:, 0] + a * p[:, 3] * c - b * p[:, 4] * s, p[:, 1] + a * p[:, 3] * s + b * p[:, 4] * c]
                )
        return np.concatenate(pts)


def segment(p0, p1, width: float, tube: bool = False) -> Primitives:
    """One segment (convenience for builders)."""
    return Primitives(np.array([[p0, p1]], float), np.array([width]), np.array([tube]), np.zeros((0, 6)))


def segments(seg: np.ndarray, width: float | np.ndarray, tube: bool = False) -> Primitives:
    """Many segments (K, 2, 3) of one width."""
    seg = np.asarray(seg, float).reshape(-1, 2, 3)
    return Primitives(
        seg, np.broadcast_to(np.asarray(width, float), (len(seg),)).copy(), np.full(len(seg), tube), np.zeros((0, 6))
    )


def patch(cx: float, cy: float, z: float, hl: float, hw: float, rot: float = 0.0) -> Primitives:
    """One horizontal rectangle."""
    return Primitives(np.zeros((0, 2, 3)), np.zeros(0), np.zeros(0, bool), np.array([[cx, cy, z, hl, hw, rot]], float))


def sample_segments(
    prim: Primitives,
    density: np.ndarray | float,
    rng: np.random.Generator,
    *,
    beam: float,
    vertical_factor: float,
    patch_density: np.ndarray | float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Draw airborne returns on primitives.

    Parameters
    ----------
    prim
        The primitives.
    density
        Local pulse density (pts/m²) per segment (array of M) or one value.
    rng
        Random generator.
    beam
        Extra effective width added to members (beam footprint catching edges).
    vertical_factor
        Exposure of vertical surfaces relative to horizontal ones.
    patch_density
        Density on patches (defaults to ``density`` when scalar, else its mean).

    Returns
    -------
    points, owner
        (N, 3) coordinates and (N,) index of the primitive (segments first, then
        patches offset by M).
    """
    seg = prim.seg
    m = len(seg)
    d = seg[:, 1] - seg[:, 0]
    length = np.linalg.norm(d, axis=1)
    horiz = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_e = np.where(length > 0, horiz / length, 0.0)
    sin_e = np.sqrt(np.clip(1 - cos_e**2, 0, 1))
    weff = prim.width + beam
    lam = np.asarray(density, float) * length * weff * (cos_e + vertical_factor * sin_e)
    n = rng.poisson(np.broadcast_to(lam, (m,)))
    own = np.repeat(np.arange(m), n)
    t = rng.random(own.size)
    pts = seg[own, 0] + t[:, None] * d[own]
    # offset perpendicular to the axis: on the surface for tubes, within the width for members
    r = rng.normal(size=(own.size, 3))
    axis = d[own] / np.maximum(length[own], 1e-9)[:, None]
    r -= (r * axis).sum(axis=1, keepdims=True) * axis
    r /= np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-9)
    rad = np.where(prim.tube[own], prim.width[own] / 2, rng.uniform(-0.5, 0.5, own.size) * prim.width[own])
    pts += r * rad[:, None]
    if len(prim.patch):
        p = prim.patch
        pd = (
            patch_density
            if patch_density is not None
            else (density if np.ndim(density) == 0 else float(np.mean(density)) if m else 10.0)
        )
        area = 4 * p[:, 3] * p[:, 4]
        k = rng.poisson(np.asarray(pd, float) * area)
        po = np.repeat(np.arange(len(p)), k)
        a = rng.uniform(-1, 1, po.size) * p[po, 3]
        b = rng.uniform(-1, 1, po.size) * p[po, 4]
        c, s = np.cos(p[po, 5]), np.sin(p[po, 5])
        pp = np.c_[p[po, 0] + a * c - b * s, p[po, 1] + a * s + b * c, p[po, 2]]
        pts = np.concatenate([pts, pp])
        own = np.concatenate([own, po + m])
    return pts, own
