"""Power lines: line routes across the zone, tower stations and catenary wires.

A line is a straight or deflecting polyline that crosses the whole zone; towers
stand every 200-400 m along it (always at deflection vertices, oriented along the
bisector), conductors and shield wires hang between consecutive towers as
catenaries. Some lines are doubled 24-38 m aside (towers closer than 40 m). With
``one_side_share`` or ``no_earth_wire_share`` some lines are strung otherwise (:func:`strung`):
a double-circuit line with one circuit hung, all on one side of its towers, or a line
without an earth wire.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from towerpipe.synth.params import SceneParams
from towerpipe.synth.primitives import Primitives, segments
from towerpipe.synth.rng import derive
from towerpipe.synth.towers import HEIGHTS, Tower, place_tower


@dataclass
class PowerLines:
    """The power-line content of a zone.

    Attributes
    ----------
    towers
        Towers inside the zone (ids 1..n), in line order.
    wires
        Segments of all wires (catenaries discretised at ~2 m).
    axes
        2-D polylines (k, 2) of every line route (for corridor clearing).
    spans
        (S, 2) pairs of consecutive tower ids joined by wires (both inside the zone).
    stringing
        Line id → how a line strung otherwise than in full is strung (:func:`strung`'s
        ``"one side"``, ``"no earth wire"`` or both); lines strung in full are not listed.
    """

    towers: list[Tower]
    wires: Primitives
    axes: list[np.ndarray]
    spans: np.ndarray
    stringing: dict[int, str] = field(default_factory=dict)


def catenary(a: np.ndarray, b: np.ndarray, param: float, step: float = 2.0) -> np.ndarray:
    """Points of a catenary hanging between 3-D points ``a`` and ``b``.

    ``param`` is the catenary parameter (horizontal tension / weight per metre, m);
    the sag at mid-span is about span² / (8 param).
    """
    span = float(np.hypot(*(b[:2] - a[:2])))
    n = max(2, int(np.ceil(span / step)) + 1)
    t = np.linspace(0, 1, n)
    s = t * span
    chord = a[None, :] + t[:, None] * (b - a)[None, :]
    sag = param * (np.cosh((s - span / 2) / param) - np.cosh(span / (2 * param)))
    chord[:, 2] += sag
    return chord


#: A design hangs two circuits when it has at least this many conductor attachments on each side.
CIRCUIT_CONDUCTORS = 3


def strung(tower: Tower, one_side: int = 0, earth_wire: bool = True) -> np.ndarray:
    """Which of a tower's attachments carry a wire, on a line strung otherwise than in full.

    Parameters
    ----------
    tower
        A placed tower (its ``attach`` in world coordinates).
    one_side
        ``+1`` or ``-1``: a double-circuit design (:data:`CIRCUIT_CONDUCTORS` conductor
        attachments or more on each side) carries one circuit only, on that side of the line
        (the local x axis); other designs keep both sides. ``0``: both sides.
    earth_wire
        ``False``: the attachments at the tower's top (the earth wires) carry nothing.

    Returns
    -------
    numpy.ndarray
        ``(K,)`` bool over ``tower.attach``; the same for every tower of one design, so the
        wires still join consecutive towers.
    """
    a = np.asarray(tower.attach, np.float64).reshape(-1, 3)
    c, s = np.cos(tower.rot), np.sin(tower.rot)
    across = c * (a[:, 0] - tower.x) + s * (a[:, 1] - tower.y)
    top = a[:, 2] - tower.base_z >= tower.height - 0.05
    keep = np.ones(len(a), bool)
    if not earth_wire:
        keep &= ~top
    left, right = ~top & (across < -0.5), ~top & (across > 0.5)
    if one_side and min(left.sum(), right.sum()) >= CIRCUIT_CONDUCTORS:
        keep &= ~(right if one_side < 0 else left)
    return keep


def _stringing(seed: int, line: int, params: SceneParams) -> tuple[int, bool]:
    """How a line is strung (:func:`strung`'s ``one_side`` and ``earth_wire``). Nothing is drawn
    when both shares are 0, so zones without them are generated as before."""
    if params.one_side_share <= 0 and params.no_earth_wire_share <= 0:
        return 0, True
    r = derive(seed, "stringing", line)
    side = int(r.choice([-1, 1])) if r.random() < params.one_side_share else 0
    return side, not r.random() < params.no_earth_wire_share


def _route(rng: np.random.Generator, bounds, params: SceneParams, through=None, angle=None) -> np.ndarray:
    """A polyline crossing the zone (extended one span beyond it on both sides)."""
    xmin, ymin, xmax, ymax = bounds
    diag = np.hypot(xmax - xmin, ymax - ymin)
    ext = diag / 2 + params.span[1] * 1.5
    p = np.array(through if through is not None else [rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)], float)
    ang = rng.uniform(0, np.pi) if angle is None else angle
    nd = int(rng.integers(params.deflections[0], params.deflections[1] + 1))
    # vertices: start, deflections, end, total length 2*ext, passing near p
    lengths = rng.dirichlet(np.ones(nd + 1)) * 2 * ext
    turns = rng.uniform(np.radians(5), np.radians(40), nd) * rng.choice([-1, 1], nd)
    heads = ang + np.concatenate([[0.0], np.cumsum(turns)])
    steps = np.c_[np.cos(heads), np.sin(heads)] * lengths[:, None]
    verts = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    # shift so that the route's point nearest to its middle passes through p
    mid = _along(verts, np.array([ext]))[0]
    return verts - mid + p


def _along(verts: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``s`` along a polyline."""
    seg = np.diff(verts, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    t = (s - cum[i]) / np.maximum(cum[i + 1] - cum[i], 1e-9)
    return verts[i] + t[:, None] * seg[i]


def _stations(rng: np.random.Generator, verts: np.ndarray, params: SceneParams, anchor_s=None):
    """Arc lengths of towers: every vertex plus evenly split 200-400 m spans."""
    seg = np.diff(verts, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    if anchor_s is not None:  # a forced tower: equal spans outward from it on a straight route
        sp = rng.uniform(*params.span)
        k = np.arange(-int(anchor_s // sp), int((cum[-1] - anchor_s) // sp) + 1)
        return anchor_s + k * sp
    out = [0.0]
    for a, b in zip(cum[:-1], cum[1:]):
        n = max(1, int(round((b - a) / rng.uniform(*params.span))))
        out.extend(list(a + (b - a) * np.arange(1, n + 1) / n))
    return np.array(out)


def _heading(verts: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Direction of the line at arc lengths s (bisector at vertices)."""
    e = 1.0
    p0 = _along(verts, np.maximum(s - e, 0))
    p1 = _along(verts, s + e)
    d = p1 - p0
    return np.arctan2(d[:, 1], d[:, 0])


def make_power_lines(
    seed: int,
    bounds,
    params: SceneParams,
    terrain_z,
    *,
    block_edges: list[tuple[float, float, float, float]] | None = None,
) -> PowerLines:
    """Lay out lines, towers and wires over the zone.

    Parameters
    ----------
    seed
        Zone seed.
    bounds
        Zone (xmin, ymin, xmax, ymax).
    params
        Scene parameters.
    terrain_z
        Callable (x, y) -> ground elevation.
    block_edges
        Inner block edges as segments (x0, y0, x1, y1); with ``params.edge_tower``
        one extra line puts a tower exactly on one of them.
    """
    rng = derive(seed, "lines")
    xmin, ymin, xmax, ymax = bounds
    area = (xmax - xmin) * (ymax - ymin) / 1e6
    n_lines = max(params.min_lines, int(rng.poisson(params.lines_per_km2 * area)))
    w = np.asarray(params.design_weights, float)
    routes = []  # (verts, design, anchor_s: the forced tower's arc length, rng, beside: the line a twin stands beside)
    for li in range(n_lines):
        r = derive(seed, "line", li)
        verts = _route(r, bounds, params)
        design = str(r.choice(params.designs, p=w / w.sum()))
        routes.append((verts, design, None, r, None))
        if r.random() < params.parallel_line_share:
            seg = np.diff(verts, axis=0)
            off = r.uniform(*params.parallel_gap) * r.choice([-1, 1])
            # offset every vertex along the normal of its first segment (routes stay parallel)
            nrm = np.c_[-seg[:, 1], seg[:, 0]] / np.hypot(seg[:, 0], seg[:, 1])[:, None]
            nrm = np.vstack([nrm, nrm[-1:]])
            d2 = str(r.choice(params.designs, p=w / w.sum()))
            rt = derive(seed, "line-twin", li)
            # towers beside the first line's: its stations (an index into routes), moved 0-2 m along
            beside = (
                len(routes) - 1 if params.twin_beside_share > 0 and rt.random() < params.twin_beside_share else None
            )
            routes.append((verts + off * nrm, d2, None, rt, beside))
    if params.edge_tower and block_edges:
        r = derive(seed, "edge-line")
        x0, y0, x1, y1 = block_edges[int(r.integers(len(block_edges)))]
        t = r.uniform(0.3, 0.7)
        p = np.array([x0 + t * (x1 - x0), y0 + t * (y1 - y0)])
        edge_ang = np.arctan2(y1 - y0, x1 - x0)
        ang = edge_ang + r.uniform(np.radians(35), np.radians(145))
        pr = params.__class__(**{**params.__dict__, "deflections": (0, 0)})
        verts = _route(r, bounds, pr, through=p, angle=ang)
        design = str(r.choice(["lattice_waist", "double_circuit"]))
        s_anchor = float(np.hypot(*(p - verts[0])))
        routes.append((verts, design, s_anchor, r, None))

    towers: list[Tower] = []
    wires = []
    spans = []
    axes = []
    stringing: dict[int, str] = {}
    next_id = 1
    placed: list[np.ndarray] = []  # each route's stations
    for li, (verts, design, anchor, r, beside) in enumerate(routes):
        axes.append(verts)
        side, earth = _stringing(seed, li, params)
        if beside is not None:  # a twin beside the line ``beside``: its stations
            s = placed[beside] + r.uniform(-2.0, 2.0, len(placed[beside]))
        else:
            s = _stations(r, verts, params, anchor)
        placed.append(s)
        pts = _along(verts, s)
        head = _heading(verts, s)
        lo, hi = HEIGHTS[design]
        hbase = r.uniform(lo, hi)
        line_towers: list[Tower | None] = []
        for k in range(len(s)):
            hgt = float(np.clip(hbase * r.uniform(0.88, 1.12), max(10.0, lo), min(60.0, hi)))
            t = place_tower(
                0,
                design,
                pts[k, 0],
                pts[k, 1],
                head[k] - np.pi / 2,
                hgt,
                terrain_z,
                derive(seed, "tower", li, k),
                line_id=li,
            )
            if side or not earth:
                keep, one = strung(t, side, earth), strung(t, side)
                how = [w for w, cut in (("one side", ~one), ("no earth wire", one & ~keep)) if cut.any()]
                if how:
                    stringing[li] = ", ".join(how)
                t.attach = t.attach[keep]
            hull = t.prim.xy_points()
            inside = (hull[:, 0] >= xmin) & (hull[:, 0] < xmax) & (hull[:, 1] >= ymin) & (hull[:, 1] < ymax)
            if inside.all():
                t.tower_id = next_id
                next_id += 1
                line_towers.append(t)
                towers.append(t)
            elif inside.any():
                line_towers.append(None)  # would be cut by the zone edge: leave it out
            else:
                line_towers.append(t)  # outside: no points, but its wires enter the zone
        cat_a = r.uniform(*params.catenary_a)
        prev = None
        for t in line_towers:
            if t is None:
                continue
            if prev is not None and len(prev.attach) == len(t.attach):
                for a, b in zip(prev.attach, t.attach):
                    c = catenary(a, b, cat_a)
                    wires.append(np.stack([c[:-1], c[1:]], axis=1))
                if prev.tower_id and t.tower_id:
                    spans.append((prev.tower_id, t.tower_id))
            prev = t
    wprim = segments(np.concatenate(wires), params.wire_width) if wires else Primitives.empty()
    return PowerLines(towers, wprim, axes, np.array(spans, np.int64).reshape(-1, 2), stringing)


def distance_to_polylines(x: np.ndarray, y: np.ndarray, lines: list[np.ndarray]) -> np.ndarray:
    """Horizontal distance from points to the nearest of several polylines."""
    best = np.full(len(x), np.inf)
    for v in lines:
        for a, b in zip(v[:-1], v[1:]):
            d = b - a
            L2 = max(float(d @ d), 1e-12)
            t = np.clip(((x - a[0]) * d[0] + (y - a[1]) * d[1]) / L2, 0, 1)
            best = np.minimum(best, np.hypot(x - a[0] - t * d[0], y - a[1] - t * d[1]))
    return best
