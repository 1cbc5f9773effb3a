"""Transmission tower designs as sets of members (local frame: x across the line,
y along the line, z up, base centre at the origin).

Designs: ``lattice_waist`` (waist type: a short V over the waist under a beam, one circuit
in a horizontal plane), ``double_circuit`` (tall lattice, three arm levels each side),
``small_lattice`` (10-20 m, one cross-arm), ``monopole`` (tapered tube with arms), and
the European types of :data:`EUROPEAN`: ``donau`` (two arm levels, the lower one longer:
one conductor each side above, two below), ``einebenen`` (one long arm level carrying
three conductors each side), ``tonne`` (barrel: three levels, the middle arm longest),
``delta`` (a triangular head of two inclined members over a beam), ``portal`` (two
lattice columns under a lattice beam) and ``wooden_hframe`` (two wooden poles, a cross
beam and X-bracing). :data:`UTILITY` holds ``utility_pole`` (one wooden or concrete pole
of 14-30 m with one to three cross-arms) and :data:`HEADED` the lattices with a head
above a waist (``cat_head``: a closed head with short arms at its shoulders;
``wine_glass``: long legs opening in a V from a low waist to a wide beam), each drawn only
by a zone that names it in ``designs``. Every design carries insulator strings at its
conductor attachments and an earth wire at its top.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import shapely

from towerpipe.synth.primitives import Primitives, patch, segment, segments

#: The generator's first four designs (the default of :class:`~towerpipe.synth.params.SceneParams`).
CLASSIC = ("lattice_waist", "double_circuit", "small_lattice", "monopole")
#: European pylon types and wooden H-frames (training variety aimed at real towers).
EUROPEAN = ("donau", "einebenen", "tonne", "delta", "portal", "wooden_hframe")
DESIGNS = CLASSIC + EUROPEAN
#: Single utility poles: towers of the real-shape benchmark's utility family are of this kind.
#: Not in :data:`DESIGNS`, so no zone draws them unless its ``designs`` names them.
UTILITY = ("utility_pole",)
#: Lattices with a head above a waist, as most high-voltage lines of East Asia and many of
#: Eastern Europe carry them. Not in :data:`DESIGNS` either (the default zones draw as before).
HEADED = ("cat_head", "wine_glass")

#: height range (m) per design, all within 10-60 m
HEIGHTS = {
    "lattice_waist": (22.0, 40.0),
    "double_circuit": (30.0, 50.0),
    "small_lattice": (10.0, 20.0),
    "monopole": (15.0, 36.0),
    "donau": (28.0, 55.0),
    "einebenen": (22.0, 45.0),
    "tonne": (35.0, 60.0),
    "delta": (20.0, 40.0),
    "portal": (12.0, 28.0),
    "wooden_hframe": (10.0, 20.0),
    "utility_pole": (14.0, 30.0),
    "cat_head": (14.0, 50.0),
    "wine_glass": (14.0, 45.0),
}
#: designs of wood (coloured and reflecting as wood, not steel)
WOODEN = ("wooden_hframe", "utility_pole")

_CORNERS = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], float)


@dataclass
class Tower:
    """A tower placed in the zone.

    Attributes
    ----------
    tower_id
        Unique id (> 0) within the zone.
    design
        One of :data:`DESIGNS` or ``"real:<name>"``.
    x, y, base_z
        Base centre and ground elevation there.
    height
        Top above ``base_z``.
    rot
        Rotation of the local x axis (across the line), radians.
    prim
        Members in world coordinates (lattice / tube designs), or empty.
    attach
        (K, 3) world coordinates of wire attachment points (conductors, shields).
    base_width
        Width of the base (m).
    points
        Fixed point set in world coordinates (real towers), else ``None``.
    line_id
        Line the tower belongs to.
    ground
        Which of ``points`` are their source's ground (:func:`towerpipe.synth.real.ground_layer`),
        left out of the zone once their attributes are drawn; ``None``: none.
    """

    tower_id: int
    design: str
    x: float
    y: float
    base_z: float
    height: float
    rot: float
    prim: Primitives
    attach: np.ndarray
    base_width: float
    points: np.ndarray | None = None
    line_id: int = 0
    extra: dict = field(default_factory=dict)
    ground: np.ndarray | None = None

    def outline(self) -> shapely.Polygon:
        """Footprint: convex hull of the tower's horizontal projection (its ground layer left out)."""
        own = self.points if self.ground is None or self.ground.all() else self.points[~self.ground]
        xy = own[:, :2] if own is not None else self.prim.xy_points()
        return shapely.convex_hull(shapely.MultiPoint(xy)).buffer(0.25, quad_segs=2)


def lattice_body(levels: np.ndarray, half: np.ndarray, rng: np.random.Generator, member: float) -> list[np.ndarray]:
    """Square lattice body: legs, horizontals and X-bracing between ``levels``."""
    c = _CORNERS[None, :, :] * half[:, None, None]  # (L, 4, 2)
    p = np.concatenate([c, np.broadcast_to(levels[:, None, None], (len(levels), 4, 1))], axis=2)
    segs = []
    segs.append(np.stack([p[:-1], p[1:]], axis=2).reshape(-1, 2, 3))  # legs
    nxt = np.roll(p, -1, axis=1)
    segs.append(np.stack([p, nxt], axis=2).reshape(-1, 2, 3))  # horizontals
    segs.append(np.stack([p[:-1], nxt[1:]], axis=2).reshape(-1, 2, 3))  # diagonals /
    segs.append(np.stack([nxt[:-1], p[1:]], axis=2).reshape(-1, 2, 3))  # diagonals \
    return segs


def panel_levels(z0: float, z1: float, hw0: float, hw1: float) -> tuple[np.ndarray, np.ndarray]:
    """Panel levels whose height is about the local width."""
    z = [z0]
    while z[-1] < z1 - 0.5:
        w = 2 * np.interp(z[-1], [z0, z1], [hw0, hw1])
        z.append(min(z1, z[-1] + max(1.2, 0.9 * w)))
    z = np.array(z)
    return z, np.interp(z, [z0, z1], [hw0, hw1])


def _arm(z: float, hw: float, length: float, side: int, depth: float) -> np.ndarray:
    """Triangular cross-arm truss from the body face at ``x = side*hw`` to its tip."""
    tip = np.array([side * (hw + length), 0.0, z])
    a = np.array([[side * hw, hw, z], [side * hw, -hw, z], [side * hw, 0.0, z + depth]])
    segs = [[a[0], tip], [a[1], tip], [a[2], tip], [a[0], a[1]], [a[0], a[2]], [a[1], a[2]]]
    mid = (a + tip) / 2
    segs += [[mid[0], mid[1]], [mid[0], mid[2]], [mid[1], mid[2]], [a[0], mid[1]], [a[2], mid[0]]]
    return np.array(segs, float)


def build_design(design: str, height: float, rng: np.random.Generator) -> tuple[Primitives, np.ndarray, float]:
    """Members, wire attachments (local) and base width of one tower.

    Parameters
    ----------
    design
        One of :data:`DESIGNS`, :data:`UTILITY` or :data:`HEADED`.
    height
        Total height (m).
    rng
        Random generator for the free proportions.
    """
    h = float(height)
    member = 0.12
    if design == "lattice_waist":
        base = rng.uniform(0.2, 0.3) * h
        zw, zb = 0.62 * h, 0.8 * h
        hww = rng.uniform(0.6, 0.9)
        arm = rng.uniform(6.5, 10.0) * h / 32
        z, hw = panel_levels(0.0, zw, base / 2, hww)
        segs = lattice_body(z, hw, rng, member)
        # the waist opens into two inclined legs up to the beam
        legs = []
        for s in (-1, 1):
            for yy in (-hww, hww):
                legs.append([[s * hww, yy, zw], [s * arm * 0.45, yy * 1.2, zb]])
            legs.append([[s * hww, -hww, zw], [s * arm * 0.45, hww * 1.2, zb]])
        segs.append(np.array(legs))
        # horizontal beam (two chords top and bottom, both faces) with verticals / diagonals
        xs = np.linspace(-arm, arm, 9)
        beam = []
        for yy in (-1.0, 1.0):
            for zz in (zb, zb + 2.0):
                beam += [[[xs[i], yy, zz], [xs[i + 1], yy, zz]] for i in range(8)]
            beam += [[[xv, yy, zb], [xv, yy, zb + 2.0]] for xv in xs]
            beam += [[[xs[i], yy, zb], [xs[i + 1], yy, zb + 2.0]] for i in range(8)]
        beam += [[[xv, -1.0, zb], [xv, 1.0, zb]] for xv in xs]
        segs.append(np.array(beam))
        peaks = [[[s * arm * 0.55, 0, zb + 2.0], [s * arm * 0.5, 0, h]] for s in (-1, 1)]
        peaks += [[[s * arm * 0.45, -1, zb + 2.0], [s * arm * 0.5, 0, h]] for s in (-1, 1)]
        segs.append(np.array(peaks))
        cz = zb - 2.8
        ins = np.array([[[xv, 0, zb], [xv, 0, cz]] for xv in (-arm + 0.5, 0.0, arm - 0.5)])
        prim = Primitives.concat([segments(np.concatenate(segs), member), segments(ins, 0.25)])
        attach = np.array([[-arm + 0.5, 0, cz], [0, 0, cz], [arm - 0.5, 0, cz], [-arm * 0.5, 0, h], [arm * 0.5, 0, h]])
        return prim, attach, base
    if design == "double_circuit":
        base = rng.uniform(0.17, 0.3) * h
        top_hw = rng.uniform(0.7, 1.1)
        z, hw = panel_levels(0.0, h - 3.0, base / 2, top_hw)
        segs = lattice_body(z, hw, rng, member)
        segs.append(np.array([[[cx * top_hw, cy * top_hw, h - 3.0], [0, 0, h]] for cx, cy in _CORNERS]))
        gap = rng.uniform(0.11, 0.15) * h
        arm_len = rng.uniform(4.0, 7.0) * np.array([1.0, 1.25, 1.0])
        attach = []
        ins = []
        for k in range(3):
            za = h - 4.5 - k * gap
            hwa = np.interp(za, z, hw)
            for s in (-1, 1):
                segs.append(_arm(za, hwa, arm_len[k], s, 1.6))
                tip = s * (hwa + arm_len[k] - 0.3)
                ins.append([[tip, 0, za], [tip, 0, za - 2.6]])
                attach.append([tip, 0, za - 2.6])
        attach.append([0, 0, h])
        prim = Primitives.concat([segments(np.concatenate(segs), member), segments(np.array(ins), 0.25)])
        return prim, np.array(attach, float), base
    if design == "small_lattice":
        base = rng.uniform(1.4, 3.4) * h / 15
        top_hw = rng.uniform(0.25, 0.4)
        z, hw = panel_levels(0.0, h - 1.0, base / 2, top_hw)
        segs = lattice_body(z, hw, rng, 0.08)
        segs.append(np.array([[[cx * top_hw, cy * top_hw, h - 1.0], [0, 0, h]] for cx, cy in _CORNERS]))
        arm = rng.uniform(2.2, 4.0)
        za = h - 1.8
        for s in (-1, 1):
            segs.append(_arm(za, top_hw, arm, s, 0.9))
        ins = [[[s * (top_hw + arm - 0.2), 0, za], [s * (top_hw + arm - 0.2), 0, za - 1.4]] for s in (-1, 1)]
        prim = Primitives.concat([segments(np.concatenate(segs), 0.08), segments(np.array(ins), 0.2)])
        attach = np.array([[-(top_hw + arm - 0.2), 0, za - 1.4], [top_hw + arm - 0.2, 0, za - 1.4], [0, 0, h]])
        return prim, attach, base
    if design == "monopole":
        d0 = rng.uniform(0.9, 1.7)
        zs = np.linspace(0, h, 7)
        dz = np.interp(zs[:-1] + h / 12, [0, h], [d0, 0.45])
        tube = np.stack([np.c_[np.zeros(6), np.zeros(6), zs[:-1]], np.c_[np.zeros(6), np.zeros(6), zs[1:]]], axis=1)
        parts = [Primitives(tube, dz, np.ones(6, bool), np.zeros((0, 6)))]
        arm = rng.uniform(2.5, 4.0)
        attach = []
        arms = []
        levels = [h - 2.0, h - 5.0, h - 8.0] if h > 22 else [h - 2.0, h - 4.5]
        for k, za in enumerate(levels):
            for s in (-1, 1) if h > 22 or k == 0 else (1,):
                arms.append([[0, 0, za], [s * arm, 0, za]])
                arms.append([[0, 0, za - 0.8], [s * arm, 0, za]])
                attach.append([s * arm, 0, za - 1.8])
        parts.append(segments(np.array(arms), 0.22, tube=True))
        parts.append(segments(np.array([[a, [a[0], 0, a[2] + 1.8]] for a in attach]), 0.22))
        parts.append(patch(0, 0, h, 0.3, 0.3))
        attach.append([0, 0, h])
        return Primitives.concat(parts), np.array(attach, float), d0
    if design == "utility_pole":
        # one pole and one to three cross-arms near its top, each with a pair of braces and pin
        # insulators at its tips; the three conductors ride the top arm's tips and the pole top
        # (the same three attachments on every pole: the wires join consecutive poles)
        d0 = rng.uniform(0.3, 0.55)
        parts = [segment([0, 0, 0], [0, 0, h], d0, tube=True)]
        attach = []
        for k in range(int(rng.integers(1, 4))):
            za = h - 0.6 - k * rng.uniform(1.4, 2.2)
            half = rng.uniform(1.0, 2.4)
            parts.append(segment([-half, 0, za], [half, 0, za], 0.14))
            parts.append(segments(np.array([[[0, 0, za - 0.9], [s * half * 0.5, 0, za]] for s in (-1, 1)]), 0.06))
            for x in (-(half - 0.15), half - 0.15):
                parts.append(segment([x, 0, za], [x, 0, za + 0.4], 0.15))
                if k == 0:
                    attach.append([x, 0, za + 0.4])
        attach.append([0, 0, h])
        return Primitives.concat(parts), np.array(attach, float), d0
    if design in EUROPEAN:
        return _european(design, h, rng)
    if design in HEADED:
        return _headed(design, h, rng)
    raise ValueError(f"unknown tower design {design!r}")


def _lattice_with_arms(
    h: float,
    rng: np.random.Generator,
    arms: list[tuple[float, float, int]],
    base_ratio: tuple[float, float] = (0.16, 0.26),
) -> tuple[Primitives, np.ndarray, float]:
    """A square lattice body to ``h - 2`` with a peak, and truss arms at given levels.

    ``arms``: ``(height fraction, arm length, conductors per side)``; conductors hang on
    insulator strings at the tip and evenly inwards along the arm.
    """
    base = rng.uniform(*base_ratio) * h
    top_hw = rng.uniform(0.6, 1.0)
    z, hw = panel_levels(0.0, h - 2.0, base / 2, top_hw)
    segs = lattice_body(z, hw, rng, 0.12)
    segs.append(np.array([[[cx * top_hw, cy * top_hw, h - 2.0], [0, 0, h]] for cx, cy in _CORNERS]))
    ins, attach = [], []
    for frac, length, per_side in arms:
        za = frac * h
        hwa = float(np.interp(za, z, hw))
        string = rng.uniform(2.2, 3.6)
        for s in (-1, 1):
            segs.append(_arm(za, hwa, length, s, rng.uniform(1.2, 2.0)))
            for k in range(per_side):
                xk = s * (hwa + length * (1.0 - k / per_side) - 0.3)
                ins.append([[xk, 0, za], [xk, 0, za - string]])
                attach.append([xk, 0, za - string])
    attach.append([0, 0, h])
    prim = Primitives.concat([segments(np.concatenate(segs), 0.12), segments(np.array(ins), 0.25)])
    return prim, np.array(attach, float), base


def _european(design: str, h: float, rng: np.random.Generator) -> tuple[Primitives, np.ndarray, float]:
    """Members, attachments and base width of the designs of :data:`EUROPEAN`."""
    if design == "donau":
        upper = rng.uniform(0.13, 0.17) * h
        return _lattice_with_arms(h, rng, [(0.84, upper, 1), (0.68, upper * rng.uniform(1.5, 1.9), 2)])
    if design == "einebenen":
        return _lattice_with_arms(h, rng, [(0.8, rng.uniform(0.28, 0.36) * h, 3)], base_ratio=(0.18, 0.28))
    if design == "tonne":
        arm = rng.uniform(0.09, 0.12) * h
        return _lattice_with_arms(
            h, rng, [(0.88, arm, 1), (0.76, arm * rng.uniform(1.25, 1.45), 1), (0.64, arm, 1)], base_ratio=(0.14, 0.2)
        )
    if design == "delta":
        base = rng.uniform(0.18, 0.26) * h
        zb = rng.uniform(0.62, 0.7) * h
        half = rng.uniform(0.17, 0.24) * h
        z, hw = panel_levels(0.0, zb, base / 2, rng.uniform(0.6, 0.9))
        segs = lattice_body(z, hw, rng, 0.12)
        top = hw[-1]
        beam = []
        xs = np.linspace(-half, half, 9)
        for yy in (-top, top):
            beam += [[[xs[i], yy, zb], [xs[i + 1], yy, zb]] for i in range(8)]
            # the delta: two chords from the beam ends to the apex, with diagonals to the beam
            apex = [0.0, yy, h]
            beam += [[[-half, yy, zb], apex], [[half, yy, zb], apex]]
            beam += [
                [[xv, yy, zb], [xv * 0.5, yy, zb + (h - zb) * (1 - abs(xv) / half) * 0.5 + (h - zb) * 0.25]]
                for xv in xs[1:-1:2]
            ]
        beam += [[[xv, -top, zb], [xv, top, zb]] for xv in xs[::2]]
        segs.append(np.array(beam))
        string = rng.uniform(2.4, 3.4)
        tips = [-half + 0.6, 0.0, half - 0.6]
        zi = [zb, zb + (h - zb) * 0.45, zb]
        ins = np.array([[[x, 0, zz], [x, 0, zz - string]] for x, zz in zip(tips, zi)])
        attach = [[x, 0, zz - string] for x, zz in zip(tips, zi)] + [[0, 0, h]]
        prim = Primitives.concat([segments(np.concatenate(segs), 0.12), segments(ins, 0.25)])
        return prim, np.array(attach, float), base
    if design == "portal":
        gap = rng.uniform(7.0, 13.0)
        col = rng.uniform(0.5, 0.8)  # column half width
        zb = h - 1.6
        segs = []
        for cx in (-gap / 2, gap / 2):
            z, hw = panel_levels(0.0, zb, col * 1.3, col)
            for part in lattice_body(z, hw, rng, 0.1):
                part = part.copy()
                part[..., 0] += cx
                segs.append(part)
        xs = np.linspace(-gap / 2 - 1.5, gap / 2 + 1.5, 11)
        beam = []
        for yy in (-col, col):
            for zz in (zb, h):
                beam += [[[xs[i], yy, zz], [xs[i + 1], yy, zz]] for i in range(10)]
            beam += [[[xv, yy, zb], [xv, yy, h]] for xv in xs]
            beam += [[[xs[i], yy, zb], [xs[i + 1], yy, h]] for i in range(10)]
        beam += [[[xv, -col, zb], [xv, col, zb]] for xv in xs[::2]]
        segs.append(np.array(beam))
        string = rng.uniform(1.8, 2.8)
        tips = [-gap / 2 + 0.2, 0.0, gap / 2 - 0.2]
        ins = np.array([[[x, 0, zb], [x, 0, zb - string]] for x in tips])
        attach = [[x, 0, zb - string] for x in tips] + [[-gap / 2, 0, h], [gap / 2, 0, h]]
        prim = Primitives.concat([segments(np.concatenate(segs), 0.1), segments(ins, 0.22)])
        return prim, np.array(attach, float), gap + 2 * col
    if design == "wooden_hframe":
        gap = rng.uniform(3.0, 5.0)
        d = rng.uniform(0.28, 0.42)
        zc = h - rng.uniform(1.0, 1.8)
        half = gap / 2 + rng.uniform(1.2, 2.0)
        poles = np.array([[[s * gap / 2, 0, 0], [s * gap / 2 * 0.92, 0, h]] for s in (-1, 1)])
        zx0, zx1 = zc - rng.uniform(2.5, 3.5), zc - 0.3
        brace = np.array([[[-gap / 2, 0, zx0], [gap / 2, 0, zx1]], [[gap / 2, 0, zx0], [-gap / 2, 0, zx1]]])
        beam = np.array([[[-half, 0, zc], [half, 0, zc]]])
        string = rng.uniform(0.8, 1.4)
        tips = [-half + 0.3, 0.0, half - 0.3]
        ins = np.array([[[x, 0, zc], [x, 0, zc - string]] for x in tips])
        attach = [[x, 0, zc - string] for x in tips] + [[0, 0, h]]
        prim = Primitives.concat(
            [segments(poles, d, tube=True), segments(beam, 0.25, tube=True), segments(brace, 0.15), segments(ins, 0.2)]
        )
        return prim, np.array(attach, float), gap + d
    raise ValueError(f"unknown tower design {design!r}")


def place_tower(
    tower_id: int,
    design: str,
    x: float,
    y: float,
    rot: float,
    height: float,
    terrain_z,
    rng: np.random.Generator,
    line_id: int = 0,
) -> Tower:
    """Build a design and place it at (x, y) on the terrain (legs reach the ground)."""
    prim, attach, base = build_design(design, height, rng)
    base_z = float(terrain_z(np.array([x]), np.array([y]))[0])
    w = prim.transformed(x, y, base_z, rot)
    # leg feet follow the slope: end points at local z == 0 go to the terrain
    foot = np.abs(prim.seg[..., 2]) < 1e-9
    if foot.any():
        w.seg[..., 2][foot] = terrain_z(w.seg[..., 0][foot], w.seg[..., 1][foot])
    c, s = np.cos(rot), np.sin(rot)
    aw = np.c_[x + c * attach[:, 0] - s * attach[:, 1], y + s * attach[:, 0] + c * attach[:, 1], base_z + attach[:, 2]]
    return Tower(
        tower_id, design, float(x), float(y), base_z, float(height), float(rot), w, aw, float(base), line_id=line_id
    )


def _truss(p0: Sequence[float], p1: Sequence[float], depth: float, min_panels: int, panel_m: float = 1.5) -> np.ndarray:
    """A two-face truss from ``p0`` to ``p1``, its chords at ``y ± depth``: chords, ties and zigzags,
    in panels of about ``panel_m`` metres (at least ``min_panels``)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    panels = max(min_panels, int(np.hypot(p1[0] - p0[0], p1[2] - p0[2]) / panel_m))
    mid = p0 + np.linspace(0.0, 1.0, panels + 1)[:, None] * (p1 - p0)
    a, b = mid - [0.0, depth, 0.0], mid + [0.0, depth, 0.0]
    segs = [[a[i], a[i + 1]] for i in range(panels)] + [[b[i], b[i + 1]] for i in range(panels)]
    segs += [[a[i], b[i]] for i in range(panels + 1)]
    segs += [[a[i], b[i + 1]] if i % 2 else [b[i], a[i + 1]] for i in range(panels)]
    return np.array(segs, float)


def _beam(x: float, z0: float, z1: float, depth: float, min_panels: int) -> np.ndarray:
    """A horizontal beam from ``-x`` to ``x`` between ``z0`` and ``z1``: two trusses, verticals, diagonals."""
    segs = [_truss((-x, 0, zz), (x, 0, zz), depth, min_panels) for zz in (z0, z1)]
    panels = len(segs[0]) // 4  # a truss of n panels has 4n + 1 members
    xs = np.linspace(-x, x, panels + 1)
    for d in (-depth, depth):
        segs.append(np.array([[[xv, d, z0], [xv, d, z1]] for xv in xs]))
        segs.append(np.array([[[xs[i], d, z0], [xs[i + 1], d, z1]] for i in range(panels)]))
    return np.concatenate(segs)


def _headed(design: str, h: float, rng: np.random.Generator) -> tuple[Primitives, np.ndarray, float]:
    """Members, attachments and base width of the designs of :data:`HEADED`.

    ``cat_head``: the body narrows to a waist at about 55 % of the height, two legs open
    into a head (its widest at the shoulders, where short arms carry the outer phases) and
    close again under a top beam, from whose middle the centre phase hangs inside the head;
    earth-wire peaks ("ears") stand on the beam's ends. ``wine_glass``: the waist is lower
    (35-50 %) and two long legs open in a V to a wide beam carrying the three phases, with
    earth-wire horns at its ends.
    """
    base = rng.uniform(0.16, 0.24) * h
    hww = rng.uniform(0.45, 0.8) * min(1.0, h / 30.0 + 0.3)  # the waist's half width
    zw = rng.uniform(0.5, 0.62) * h if design == "cat_head" else rng.uniform(0.35, 0.5) * h
    z, hw = panel_levels(0.0, zw, base / 2, hww)
    segs = lattice_body(z, hw, rng, 0.12)
    string = rng.uniform(2.2, 3.4) * min(1.0, h / 25.0)
    ins, attach = [], []
    if design == "cat_head":
        ear = rng.uniform(0.05, 0.08) * h
        zt = h - ear  # the top beam
        zs = zw + rng.uniform(0.35, 0.5) * (zt - zw)  # the shoulders
        xs = rng.uniform(0.11, 0.17) * h
        xt = xs * rng.uniform(0.75, 1.1)
        depth = rng.uniform(0.1, 0.16) * (zt - zw)
        arm = rng.uniform(0.05, 0.09) * h
        for sx in (-1, 1):
            for a, b in (((sx * hww, 0, zw), (sx * xs, 0, zs)), ((sx * xs, 0, zs), (sx * xt, 0, zt))):
                segs.append(_truss(a, b, hww, 2))
            tip = sx * (xs + arm)
            segs.append(
                np.array(
                    [[[sx * xs, d, zs], [tip, 0, zs]] for d in (-hww, hww)] + [[[sx * xs, 0, zs + 1.2], [tip, 0, zs]]]
                )
            )
            ins.append([[tip, 0, zs], [tip, 0, zs - string]])
            attach.append([tip, 0, zs - string])
            segs.append(np.array([[[sx * xt, d, zt], [sx * xt * 1.05, 0, h]] for d in (-hww, hww)]))
            attach.append([sx * xt * 1.05, 0, h])
        segs.append(_beam(xt, zt - depth, zt, hww, 4))
        ins.append([[0, 0, zt - depth], [0, 0, zt - depth - string]])
        attach.append([0, 0, zt - depth - string])
    else:
        zb = rng.uniform(0.72, 0.84) * h
        xl = rng.uniform(0.13, 0.2) * h
        xb = xl * rng.uniform(1.05, 1.3)
        depth = rng.uniform(1.0, 1.8) * min(1.0, h / 25.0)
        for sx in (-1, 1):
            a, b = (sx * hww, 0, zw), (sx * xl, 0, zb)
            segs.append(_truss(a, b, hww, 3))
            segs.append(np.array([[[sx * xb * 0.95, d, zb + depth], [sx * xb, 0, h]] for d in (-hww, hww)]))
            attach.append([sx * xb, 0, h])
        segs.append(_beam(xb, zb, zb + depth, hww, 6))
        for xv in (-xb + 0.5, 0.0, xb - 0.5):
            ins.append([[xv, 0, zb], [xv, 0, zb - string]])
            attach.append([xv, 0, zb - string])
    prim = Primitives.concat([segments(np.concatenate(segs), 0.12), segments(np.array(ins, float), 0.25)])
    return prim, np.array(attach, float), base
