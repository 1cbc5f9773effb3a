"""Hard negatives: man-made tall thin things that are not transmission towers.

Tower cranes, lattice telecom masts, wind turbines, chimneys, street lights and
wooden utility poles (with their low-voltage wires). All are class 1 ("other
structures") except the pole wires (class 14). Tall isolated trees live in
:mod:`towerpipe.synth.vegetation`; building corners in :mod:`towerpipe.synth.buildings`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from towerpipe.synth.params import SceneParams
from towerpipe.synth.primitives import Primitives, patch, segment, segments
from towerpipe.synth.rng import derive
from towerpipe.synth.towers import lattice_body, panel_levels
from towerpipe.synth.wires import catenary


@dataclass
class Negative:
    """One hard-negative object (world coordinates)."""

    kind: str
    x: float
    y: float
    height: float
    prim: Primitives


def _crane(h: float, rng) -> Primitives:
    hw = rng.uniform(0.7, 1.0)
    z, w = panel_levels(0, h, hw, hw)
    mast = np.concatenate(lattice_body(z, w, rng, 0.1))
    jib = rng.uniform(30, 60)
    cj = rng.uniform(10, 15)
    xs = np.linspace(-cj, jib, 24)
    chords = []
    for yy, zz in ((-0.8, h), (0.8, h), (0.0, h + 1.4)):
        chords += [[[xs[i], yy, zz], [xs[i + 1], yy, zz]] for i in range(len(xs) - 1)]
    chords += [[[xs[i], -0.8, h], [xs[i + 1], 0, h + 1.4]] for i in range(len(xs) - 1)]
    chords += [[[xs[i], 0.8, h], [xs[i + 1], 0, h + 1.4]] for i in range(len(xs) - 1)]
    chords += [[[0, 0, h], [0, 0, h + 6]], [[0, 0, h + 6], [jib * 0.7, 0, h + 1.4]], [[0, 0, h + 6], [-cj, 0, h + 1.4]]]
    hook_x = rng.uniform(5, jib)
    hook = [[[hook_x, 0, h], [hook_x, 0, h - rng.uniform(5, h - 3)]]]
    return Primitives.concat(
        [
            segments(mast, 0.12),
            segments(np.array(chords), 0.12),
            segments(np.array(hook), 0.05),
            patch(-cj + 2.5, 0, h + 0.5, 2.0, 1.0),
        ]
    )


def _mast(h: float, rng) -> Primitives:
    z, w = panel_levels(0, h, rng.uniform(0.8, 1.4), 0.5)
    body = np.concatenate(lattice_body(z, w, rng, 0.08))
    parts = [segments(body, 0.08)]
    for _ in range(int(rng.integers(2, 6))):  # antennas and dishes near the top
        za = h - rng.uniform(0.5, 6)
        a = rng.uniform(0, 2 * np.pi)
        parts.append(
            segment([0.6 * np.cos(a), 0.6 * np.sin(a), za - 1.2], [0.6 * np.cos(a), 0.6 * np.sin(a), za + 1.2], 0.3)
        )
        parts.append(patch(1.0 * np.cos(a), 1.0 * np.sin(a), za, 0.5, 0.15, a))
    return Primitives.concat(parts)


def _turbine(h: float, rng) -> Primitives:
    zs = np.linspace(0, h, 9)
    d = np.interp(zs[:-1], [0, h], [rng.uniform(3.8, 4.5), 2.4])
    tube = np.stack([np.c_[np.zeros(8), np.zeros(8), zs[:-1]], np.c_[np.zeros(8), np.zeros(8), zs[1:]]], axis=1)
    parts = [Primitives(tube, d, np.ones(8, bool), np.zeros((0, 6))), patch(1.5, 0, h + 1.8, 5.0, 1.6)]
    blade = rng.uniform(35, 55)
    a0 = rng.uniform(0, 2 * np.pi)
    for k in range(3):  # blades in the vertical rotor plane x = -3
        a = a0 + k * 2 * np.pi / 3
        parts.append(segment([-3.5, 0, h + 1.5], [-3.5, blade * np.cos(a), h + 1.5 + blade * np.sin(a)], 2.0))
    return Primitives.concat(parts)


def _chimney(h: float, rng) -> Primitives:
    d = rng.uniform(2.0, 5.0)
    return Primitives.concat(
        [
            Primitives(np.array([[[0, 0, 0], [0, 0, h]]], float), np.array([d]), np.array([True]), np.zeros((0, 6))),
            patch(0, 0, h, d / 2.3, d / 2.3),
        ]
    )


_BUILDERS = {
    "crane": (_crane, (20.0, 55.0)),
    "telecom_mast": (_mast, (18.0, 50.0)),
    "wind_turbine": (_turbine, (60.0, 100.0)),
    "chimney": (_chimney, (20.0, 60.0)),
}


#: A tower crane beside a power line (:func:`crane_beside_line`): its mast this far (m) across
#: from the line's axis (its jib, 30-60 m, may swing over the conductors), this far along the
#: line from a tower.
BESIDE_LINE_ACROSS_M, BESIDE_LINE_ALONG_M = (12.0, 40.0), 80.0


def crane_beside_line(
    rng: np.random.Generator, station: np.ndarray, heading: float, terrain_z, clear, tries: int = 50
) -> Negative | None:
    """A tower crane standing beside a power line, as on a building site next to a corridor.

    Parameters
    ----------
    rng
        Random generator.
    station, heading
        A tower of the line (plan position) and the line's heading (radians).
    terrain_z
        ``terrain_z(x, y)`` of arrays: the ground height.
    clear
        ``clear(p)``: whether a crane may stand at plan position ``p`` (ground under it, no building).
    tries
        Positions drawn before giving up.

    Returns
    -------
    Negative or None
        The crane (kind ``"crane"``), ``None`` where no drawn position was clear.
    """
    along = np.array([np.cos(heading), np.sin(heading)])
    across = np.array([-np.sin(heading), np.cos(heading)])
    build, (lo, hi) = _BUILDERS["crane"]
    for _ in range(tries):
        off = rng.choice([-1.0, 1.0]) * rng.uniform(*BESIDE_LINE_ACROSS_M)
        p = np.asarray(station, float) + rng.uniform(-BESIDE_LINE_ALONG_M, BESIDE_LINE_ALONG_M) * along + off * across
        if clear(p):
            h = float(rng.uniform(lo, hi))
            z = float(terrain_z(p[:1], p[1:])[0])
            prim = build(h, rng).transformed(float(p[0]), float(p[1]), z, float(rng.uniform(0, 2 * np.pi)))
            return Negative("crane", float(p[0]), float(p[1]), h, prim)
    return None


def make_negatives(
    seed: int, bounds, params: SceneParams, terrain_z, roads, avoid
) -> tuple[list[Negative], Primitives]:
    """Draw the hard negatives of a zone.

    Returns
    -------
    objects, pole_wires
        Class-1 objects and the class-14 low-voltage wires between poles.
    """
    xmin, ymin, xmax, ymax = bounds
    area = (xmax - xmin) * (ymax - ymin) / 1e6
    out: list[Negative] = []
    rates = {
        "crane": params.cranes,
        "telecom_mast": params.telecom_masts,
        "wind_turbine": params.wind_turbines,
        "chimney": params.chimneys,
    }
    for kind, rate in rates.items():
        rng = derive(seed, "neg", kind)
        build, (lo, hi) = _BUILDERS[kind]
        n = int(rng.poisson(rate * area))
        for _ in range(n):
            x, y = rng.uniform(xmin + 30, xmax - 30), rng.uniform(ymin + 30, ymax - 30)
            if avoid(np.array([x]), np.array([y]), np.array([8.0]))[0]:
                continue
            h = rng.uniform(lo, hi)
            z = float(terrain_z(np.array([x]), np.array([y]))[0])
            out.append(Negative(kind, x, y, h, build(h, rng).transformed(x, y, z, rng.uniform(0, 2 * np.pi))))
    # poles along roads: street lights (metal, arm) or wooden poles (cross-arm + wires)
    rng = derive(seed, "neg", "poles")
    wires = []
    for verts, width in roads:
        if rng.random() >= params.poles_along_roads:
            continue
        wooden = rng.random() < 0.5
        seg = np.diff(verts, axis=0)
        cum = np.concatenate([[0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        s = np.arange(rng.uniform(0, 20), cum[-1], rng.uniform(*params.pole_spacing))
        i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        t = (s - cum[i]) / np.maximum(cum[i + 1] - cum[i], 1e-9)
        nrm = np.c_[-seg[i, 1], seg[i, 0]] / np.maximum(np.hypot(seg[i, 0], seg[i, 1]), 1e-9)[:, None]
        p = verts[i] + t[:, None] * seg[i] + nrm * (width / 2 + 1.5)
        ok = (p[:, 0] > xmin + 1) & (p[:, 0] < xmax - 1) & (p[:, 1] > ymin + 1) & (p[:, 1] < ymax - 1)
        ok &= ~avoid(p[:, 0], p[:, 1], np.full(len(p), 2.0))
        p, nrm = p[ok], nrm[ok]
        if not len(p):
            continue
        z = terrain_z(p[:, 0], p[:, 1])
        h = rng.uniform(8.0, 12.0, len(p))
        tops = []
        for k in range(len(p)):  # loop over poles (tens)
            if wooden:
                pr = Primitives.concat(
                    [
                        segment([0, 0, 0], [0, 0, h[k]], 0.3, tube=True),
                        segment([-0.9, 0, h[k] - 0.4], [0.9, 0, h[k] - 0.4], 0.12),
                    ]
                )
                tops.append([[-0.8, 0, h[k] - 0.3], [0.8, 0, h[k] - 0.3]])
                name = "wooden_pole"
            else:
                pr = Primitives.concat(
                    [
                        segment([0, 0, 0], [0, 0, h[k]], 0.2, tube=True),
                        segment([0, 0, h[k]], [-1.6, 0, h[k] + 0.2], 0.12, tube=True),
                        patch(-1.6, 0, h[k] + 0.1, 0.35, 0.15),
                    ]
                )
                name = "street_light"
            rot = np.arctan2(nrm[k, 1], nrm[k, 0])
            out.append(
                Negative(name, float(p[k, 0]), float(p[k, 1]), float(h[k]), pr.transformed(p[k, 0], p[k, 1], z[k], rot))
            )
            if wooden:
                c, s_ = np.cos(rot), np.sin(rot)
                tops[-1] = [[p[k, 0] + c * a - s_ * b, p[k, 1] + s_ * a + c * b, z[k] + cz] for a, b, cz in tops[-1]]
        if wooden:
            for a, b in zip(tops[:-1], tops[1:]):
                for pa, pb in zip(a, b):
                    c = catenary(np.array(pa), np.array(pb), 400.0)
                    wires.append(np.stack([c[:-1], c[1:]], axis=1))
    return out, (segments(np.concatenate(wires), 0.06) if wires else Primitives.empty())
