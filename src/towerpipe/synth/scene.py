"""Zone assembly: scene content over the whole zone, cut into adjoining blocks.

:func:`build_zone` draws terrain, flight strips, power lines, roads, buildings,
vegetation and hard negatives over the zone extent; :func:`block_points` turns the
part of the zone inside one block into airborne returns (pulses of the scan
pattern for 2.5-D surfaces, airborne-calibrated sampling of thin 3-D structures),
so that objects crossing a block edge stay continuous.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from towerpipe.classes import BUILDING, GROUND, HIGH_NOISE, LOW_NOISE, OTHER, ROAD, TOWER
from towerpipe.classes import HIGH_VEGETATION as HIGH_VEG
from towerpipe.classes import LOW_VEGETATION as LOW_VEG
from towerpipe.classes import MEDIUM_VEGETATION as MED_VEG
from towerpipe.classes import WIRE_CONDUCTOR as WIRE
from towerpipe.synth import color as col
from towerpipe.synth.buildings import (
    Buildings,
    make_buildings,
    make_roads,
    rasterize_roads,
    rasterize_roofs,
    sample_walls,
)
from towerpipe.synth.delivery import SOURCE_GROUND, drop_source_ground
from towerpipe.synth.negatives import Negative, crane_beside_line, make_negatives
from towerpipe.synth.params import SceneParams
from towerpipe.synth.primitives import Primitives, sample_segments
from towerpipe.synth.rng import derive
from towerpipe.synth.sensor import FlightPlan, make_flight_plan, pulses
from towerpipe.synth.terrain import Terrain, make_terrain
from towerpipe.synth.towers import WOODEN, Tower
from towerpipe.synth.vegetation import Trees, make_trees, noise_field, rasterize
from towerpipe.synth.wires import PowerLines, distance_to_polylines, make_power_lines

_NEG_MATERIAL = {
    "crane": col.STEEL,
    "telecom_mast": col.STEEL,
    "wind_turbine": col.CONCRETE,
    "chimney": col.CONCRETE,
    "street_light": col.STEEL,
    "wooden_pole": col.WOOD,
}

#: raster resolution of canopy / roofs / roads (m)
RASTER_RES = 0.5


def block_grid(blocks: int) -> tuple[int, int]:
    """(columns, rows) of the most square factorisation of ``blocks``."""
    best = (blocks, 1)
    for r in range(1, int(math.isqrt(blocks)) + 1):
        if blocks % r == 0:
            best = (blocks // r, r)
    return best


def block_name(xmin: float, ymin: float) -> str:
    """Block file stem from its lower-left corner."""
    return f"{int(round(xmin))}_{int(round(ymin))}"


@dataclass
class Zone:
    """Everything drawn over a zone before it is cut into blocks."""

    seed: int
    bounds: tuple[float, float, float, float]
    blocks: list[tuple[float, float, float, float]]
    density: float
    params: SceneParams
    terrain: Terrain
    plan: FlightPlan
    lines: PowerLines
    roads: list
    buildings: Buildings
    trees: Trees
    negatives: list[Negative]
    pole_wires: Primitives
    greenness: object
    extra_towers: list[Tower] = field(default_factory=list)

    @property
    def towers(self) -> list[Tower]:
        """All towers with points (line towers inside the zone and inserted ones)."""
        return self.lines.towers + self.extra_towers


def build_zone(
    seed: int,
    *,
    blocks: int = 4,
    size: float = 250.0,
    density: float = 10.0,
    origin: tuple[float, float] = (400000.0, 4600000.0),
    params: SceneParams | None = None,
    tower_factory=None,
) -> Zone:
    """Draw the content of a zone.

    Parameters
    ----------
    seed
        Zone seed (every object kind uses its own derived stream).
    blocks, size, origin
        ``blocks`` adjoining square blocks of side ``size`` from the lower-left ``origin``.
    density
        Requested point density (all returns, pts/m²).
    params
        Scene parameters (default: the "catalonia" preset).
    tower_factory
        Optional callable ``(tower, rng) -> tower`` replacing synthetic towers (real shapes).
    """
    params = params or SceneParams()
    nc, nr = block_grid(int(blocks))
    x0, y0 = origin
    bl = [
        (x0 + i * size, y0 + j * size, x0 + (i + 1) * size, y0 + (j + 1) * size) for j in range(nr) for i in range(nc)
    ]
    bounds = (x0, y0, x0 + nc * size, y0 + nr * size)
    terrain = make_terrain(seed, bounds, params)
    plan = make_flight_plan(seed, bounds, params, density)
    edges = [(x0 + i * size, y0, x0 + i * size, y0 + nr * size) for i in range(1, nc)]
    edges += [(x0, y0 + j * size, x0 + nc * size, y0 + j * size) for j in range(1, nr)]
    lines = make_power_lines(seed, bounds, params, terrain.z, block_edges=edges)
    if tower_factory is not None:
        lines.towers = [tower_factory(t, derive(seed, "real-tower", t.tower_id)) for t in lines.towers]
    roads = make_roads(seed, bounds, params)
    txy = np.array([[t.x, t.y] for t in lines.towers]).reshape(-1, 2)

    def avoid(x, y, rad):
        bad = np.zeros(len(x), bool)
        if roads:
            bad |= distance_to_polylines(x, y, [v for v, _ in roads]) < rad + 6.0
        if len(txy):
            d = np.hypot(x[:, None] - txy[None, :, 0], y[:, None] - txy[None, :, 1]).min(axis=1)
            bad |= d < rad + 20.0
        if lines.axes:
            bad |= distance_to_polylines(x, y, lines.axes) < rad + 12.0
        return bad

    buildings = make_buildings(seed, bounds, params, terrain.z, avoid)
    negatives, pole_wires = make_negatives(seed, bounds, params, terrain.z, roads, avoid)
    negatives += _cranes_beside_lines(seed, bl, lines.towers, params.cranes_beside_lines, terrain.z, avoid)
    trees = make_trees(seed, bounds, params)
    # corridor clearing under the wires
    if lines.axes and len(trees):
        r = derive(seed, "corridor")
        under = distance_to_polylines(trees.x, trees.y, lines.axes) < 14.0
        cut = under & (r.random(len(trees)) < params.corridor_clearing) & (trees.h > 3.0)
        newh = r.uniform(0.5, 3.0, len(trees))
        trees.base = np.where(cut, trees.base * newh / trees.h, trees.base)
        trees.r = np.where(cut, np.minimum(trees.r, 1.5), trees.r)
        trees.h = np.where(cut, newh, trees.h)
    greenness = noise_field(seed, "greenness", 120.0)
    return Zone(
        seed,
        bounds,
        bl,
        density,
        params,
        terrain,
        plan,
        lines,
        roads,
        buildings,
        trees,
        negatives,
        pole_wires,
        greenness,
    )


def _cranes_beside_lines(seed: int, blocks, towers: list[Tower], per_block: int, terrain_z, avoid) -> list[Negative]:
    """``per_block`` tower cranes in each block that holds a line tower, each beside one of its
    towers (:func:`towerpipe.synth.negatives.crane_beside_line`), standing inside the block and
    clear of roads, towers and the lines' axes."""
    out: list[Negative] = []
    if per_block <= 0 or not towers:
        return out
    rng = derive(seed, "neg", "crane_beside_line")
    txy = np.array([[t.x, t.y] for t in towers])
    for b in blocks:
        here = np.flatnonzero(_in(b, txy[:, 0], txy[:, 1]))
        if not len(here):
            continue

        def clear(p, b=b) -> bool:
            return bool(_in(b, p[:1], p[1:])[0] and not avoid(p[:1], p[1:], 1.0)[0])

        for _ in range(int(per_block)):
            t = towers[int(here[int(rng.integers(len(here)))])]
            neg = crane_beside_line(rng, np.array([t.x, t.y]), float(t.rot) + math.pi / 2, terrain_z, clear)
            if neg is not None:
                out.append(neg)
    return out


def _in(b, x, y) -> np.ndarray:
    return (x >= b[0]) & (x < b[2]) & (y >= b[1]) & (y < b[3])


def _prim_bbox_hit(prim: Primitives, b, margin: float = 2.0) -> bool:
    if not len(prim.seg) and not len(prim.patch):
        return False
    xy = prim.xy_points()
    return bool(
        (xy[:, 0].max() >= b[0] - margin)
        & (xy[:, 0].min() < b[2] + margin)
        & (xy[:, 1].max() >= b[1] - margin)
        & (xy[:, 1].min() < b[3] + margin)
    )


def block_points(zone: Zone, index: int) -> dict[str, np.ndarray]:
    """All returns of one block.

    Returns
    -------
    dict
        ``x, y, z`` (float64), ``classification`` (uint8), ``tower_id`` (uint32),
        ``return_number``, ``number_of_returns`` (uint8), ``intensity``, ``red``,
        ``green``, ``blue``, ``nir`` (uint16), ``point_source_id`` (uint16),
        ``scan_angle`` (float32, degrees), ``gps_time`` (float64), sorted by GPS time.
    """
    p = zone.params
    b = zone.blocks[index]
    ix = int(round((b[0] - zone.bounds[0]) / (b[2] - b[0])))
    iy = int(round((b[1] - zone.bounds[1]) / (b[3] - b[1])))
    rng = derive(zone.seed, "block", ix, iy)
    area = (b[2] - b[0]) * (b[3] - b[1])
    target = zone.density * area

    # ---- rasters of the block -------------------------------------------------
    tr = zone.trees
    m = (tr.x + tr.r >= b[0]) & (tr.x - tr.r < b[2]) & (tr.y + tr.r >= b[1]) & (tr.y - tr.r < b[3])
    trees = tr.subset(m)
    can = rasterize(trees, b, RASTER_RES, rng)
    bu = zone.buildings
    bm = (bu.x + bu.length >= b[0]) & (bu.x - bu.length < b[2]) & (bu.y + bu.length >= b[1]) & (bu.y - bu.length < b[3])
    bsub = bu.subset(bm)
    roof, bid = rasterize_roofs(bsub, can.x0, can.y0, RASTER_RES, can.nx, can.ny)
    road = rasterize_roads(zone.roads, can.x0, can.y0, RASTER_RES, can.nx, can.ny)
    hasroof = ~np.isnan(roof)
    can.top[hasroof | road] = 0.0
    can.tree[hasroof | road] = -1

    # ---- pulses and their returns -------------------------------------------------
    # pre-thin the pulse rate by the block's mean strip coverage and ~1.05 returns per pulse
    probe = rng.random((2000, 2)) * [b[2] - b[0], b[3] - b[1]] + [b[0], b[1]]
    cover = max(float(zone.plan.coverage(probe[:, 0], probe[:, 1]).mean()), 1.0)
    pre = min(1.0, 1.0 / (1.05 * cover))
    pu = pulses(zone.plan, b, rng, p.pulse_jitter, thin=pre)
    cell = can.cell(pu["x"], pu["y"])
    top = can.top[cell]
    isroof = hasroof[cell]
    veg = (top > 0.05) & ~isroof
    n = len(cell)
    hit1 = veg & (rng.random(n) > p.canopy_gap)
    hit2 = veg & (rng.random(n) < np.clip(0.25 + top / 25.0, 0, 0.7))
    gnd = ~isroof & (~veg | ~(hit1 | hit2) | (rng.random(n) < p.canopy_transmission))
    nret = hit1.astype(np.int64) + hit2 + gnd + isroof
    # objects take part of the budget; thin pulses so that the block meets the density
    keep_p = min(1.0, 0.985 * target / max(nret.sum(), 1))
    keep = rng.random(n) < keep_p
    sel = np.flatnonzero(keep)
    pu = {k: v[sel] for k, v in pu.items()}
    cell, top, isroof, veg, hit1, hit2, gnd, nret = (a[sel] for a in (cell, top, isroof, veg, hit1, hit2, gnd, nret))
    n = len(sel)
    gz = zone.terrain.z(pu["x"], pu["y"])
    base = np.minimum(can.base[cell], top)
    z1 = top - np.abs(rng.normal(0, 0.25, n)) - rng.exponential(0.35, n) * (top > 3)
    z1 = np.clip(z1, np.minimum(base, top * 0.5), top)
    incrown = rng.random(n) < 0.7
    z2 = np.where(
        incrown, base + (top - base) * rng.random(n) ** 0.8, rng.uniform(0.15, 1.0, n) * np.maximum(base, 0.3)
    )
    z2 = np.minimum(z2, np.where(hit1, z1 - 0.6, top))
    z2 = np.maximum(z2, 0.05)
    # candidates (n, 4): canopy 1, canopy 2, ground, roof — already in decreasing height order
    cz = np.stack([gz + z1, gz + z2, gz, roof[cell]], axis=1)
    cm = np.stack([hit1, hit2 & (z2 > 0.05), gnd, isroof], axis=1)
    nret = cm.sum(axis=1)
    rnum = np.cumsum(cm, axis=1)
    pi_, ci = np.nonzero(cm)
    z = cz[pi_, ci]
    hag = z - gz[pi_]
    cls = np.select([ci == 3, ci == 2, hag < 3.0, hag < 8.0], [BUILDING, GROUND, LOW_VEG, MED_VEG], HIGH_VEG)
    cls = np.where((ci == 2) & road[cell[pi_]], ROAD, cls).astype(np.uint8)
    # the surface seen from above (colour of every return of the pulse)
    top_mat = np.where(isroof, col.ROOF, np.where(veg, col.TREE, np.where(road[cell], col.ROAD, col.GROUND)))
    top_var = np.where(isroof, bsub.roof[np.maximum(bid[cell], 0)] if len(bsub) else 0, can.tree[cell])
    mat_surface = top_mat[pi_]
    pts = {
        "x": pu["x"][pi_],
        "y": pu["y"][pi_],
        "z": z,
        "classification": cls,
        "tower_id": np.zeros(len(pi_), np.uint32),
        "return_number": rnum[pi_, ci].astype(np.uint8),
        "number_of_returns": nret[pi_].astype(np.uint8),
        "strip": pu["strip"][pi_],
        "scan_angle": pu["scan_angle"][pi_],
        "gps_time": pu["gps_time"][pi_] + ci * 1e-8,
        "material": np.where(ci == 2, np.where(veg[pi_], col.GROUND, mat_surface), mat_surface),
        "color_material": mat_surface,
        "color_variant": top_var[pi_],
        "intensity_factor": np.ones(len(pi_)),
    }
    # ground returns under canopy keep the canopy colour; intensity uses their own material

    # ---- thin 3-D structures ------------------------------------------------------------
    strip_density = zone.density * keep_p * pre
    parts = [pts]

    def lookup_surface(x, y):
        c = can.cell(x, y)
        mat = np.where(
            hasroof[c], col.ROOF, np.where(can.top[c] > 0.05, col.TREE, np.where(road[c], col.ROAD, col.GROUND))
        )
        var = np.where(hasroof[c], bsub.roof[np.maximum(bid[c], 0)] if len(bsub) else 0, can.tree[c])
        return mat, var, can.top[c]

    def add(xyz, klass, material, own_share, tid=None, single=False, intensity_factor=1.0):
        keep = _in(b, xyz[:, 0], xyz[:, 1])
        xyz = xyz[keep]
        k = len(xyz)
        if not k:
            return
        klass = np.asarray(klass)[keep] if np.ndim(klass) else klass  # per point: a real tower's ground layer
        smat, svar, _ = lookup_surface(xyz[:, 0], xyz[:, 1])
        own = rng.random(k) < own_share
        strip, ang, t = zone.plan.attributes(xyz[:, 0], xyz[:, 1], rng)
        nr = np.ones(k, np.uint8) if single else (1 + (rng.random(k) < 0.6)).astype(np.uint8)
        rn = np.where((nr == 2) & (rng.random(k) < 0.25), 2, 1).astype(np.uint8)
        parts.append(
            {
                "x": xyz[:, 0],
                "y": xyz[:, 1],
                "z": xyz[:, 2],
                "classification": np.full(k, klass, np.uint8),
                "tower_id": (np.zeros(k, np.uint32) if tid is None else np.asarray(tid, np.uint32)[keep]),
                "return_number": rn,
                "number_of_returns": nr,
                "strip": strip,
                "scan_angle": ang.astype(np.float32),
                "gps_time": t,
                "material": np.full(k, material),
                "color_material": np.where(own, material, smat),
                "color_variant": np.where(own, 0, svar),
                "intensity_factor": np.full(k, intensity_factor),
            }
        )

    def local_density(prim: Primitives) -> np.ndarray:
        mid = prim.seg.mean(axis=1) if len(prim.seg) else np.zeros((0, 3))
        return strip_density * np.maximum(zone.plan.coverage(mid[:, 0], mid[:, 1]), 1)

    for t in zone.towers:
        if t.points is None and not _prim_bbox_hit(t.prim, b):
            continue
        if t.points is not None:
            xyz = t.points
            if not len(xyz) or not _in((b[0] - 30, b[1] - 30, b[2] + 30, b[3] + 30), t.x, t.y):
                continue
        else:
            r = derive(zone.seed, "tower-points", t.tower_id, ix, iy)
            xyz, _ = sample_segments(
                t.prim,
                local_density(t.prim),
                r,
                beam=p.member_beam,
                vertical_factor=p.vertical_factor,
                patch_density=strip_density * float(zone.plan.coverage([t.x], [t.y])[0]),
            )
            zrel = np.clip((xyz[:, 2] - t.base_z) / t.height, 0, 1)
            vis = p.tower_visibility_min + (1 - p.tower_visibility_min) * zrel**0.6
            _, _, ctop = lookup_surface(xyz[:, 0], xyz[:, 1])
            under = (xyz[:, 2] - zone.terrain.z(xyz[:, 0], xyz[:, 1])) < ctop
            vis = vis * np.where(under, p.canopy_transmission, 1.0)
            xyz = xyz[r.random(len(xyz)) < vis]
        own, factor = _tower_look(zone, t)
        ground = t.ground if t.ground is not None else np.zeros(len(xyz), bool)  # a real shape's source ground
        add(
            xyz,
            np.where(ground, SOURCE_GROUND, TOWER),
            col.WOOD if t.design in WOODEN else col.STEEL,
            own,
            tid=np.where(ground, 0, t.tower_id),
            intensity_factor=factor,
        )
    for wires, share in ((zone.lines.wires, 0.3), (zone.pole_wires, 0.3)):
        if not len(wires.seg):
            continue
        mid = wires.seg.mean(axis=1)
        ws = _in((b[0] - 3, b[1] - 3, b[2] + 3, b[3] + 3), mid[:, 0], mid[:, 1])
        if ws.any():
            sub = Primitives(wires.seg[ws], wires.width[ws], wires.tube[ws], np.zeros((0, 6)))
            xyz, _ = sample_segments(sub, local_density(sub), rng, beam=0.0, vertical_factor=p.vertical_factor)
            add(xyz, WIRE if p.wire_class else OTHER, col.WIRE, share)
    for neg in zone.negatives:
        if not _prim_bbox_hit(neg.prim, b):
            continue
        xyz, _ = sample_segments(
            neg.prim,
            local_density(neg.prim),
            rng,
            beam=p.member_beam,
            vertical_factor=p.vertical_factor,
            patch_density=strip_density,
        )
        add(xyz, OTHER, _NEG_MATERIAL[neg.kind], 0.7)
    if len(bsub):
        xyz, wb = sample_walls(bsub, strip_density, p.vertical_factor, rng)
        add(xyz, BUILDING, col.ROOF, 0.0)
    # ---- noise -------------------------------------------------------------------------
    for klass, rate, lo, hi in (
        (LOW_NOISE, p.noise_low, -25.0, -0.8),
        (HIGH_NOISE, p.noise_high, 20.0, p.noise_high_max),
    ):
        k = int(rng.poisson(rate * target / 1e6))
        x = rng.uniform(b[0], b[2], k)
        y = rng.uniform(b[1], b[3], k)
        dz = lo + (hi - lo) * rng.random(k) ** (2.0 if klass == HIGH_NOISE else 1.0)
        add(np.c_[x, y, zone.terrain.z(x, y) + dz], klass, col.GROUND, 0.0, single=True)

    out = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    # pulse returns are in acquisition order (strip by strip); structures, walls and noise follow
    green = _green_lookup(zone, b, out["x"], out["y"])
    c = col.colors(out["color_material"], out["color_variant"], green, rng)
    rgbn = col.to16(c)
    out["red"], out["green"], out["blue"], out["nir"] = (rgbn[:, i] for i in range(4))
    inten = col.intensity(out["material"], out["return_number"], out["number_of_returns"], rng)
    factor = out.pop("intensity_factor")
    out["intensity"] = inten if np.all(factor == 1.0) else np.clip(inten * factor, 0, 65535).astype(np.uint16)
    out["point_source_id"] = (out.pop("strip") + 1).astype(np.uint16)
    for k in ("material", "color_material", "color_variant"):
        out.pop(k)
    return drop_source_ground(out)  # after every draw: the other points stay as they were


def _tower_look(zone: Zone, t: Tower) -> tuple[float, float]:
    """``(own colour share, intensity factor)`` of one tower, the same in every block it touches."""
    lo, hi = zone.params.tower_own_color
    ilo, ihi = zone.params.tower_intensity
    if lo == hi and ilo == ihi:
        return float(lo), float(ilo)
    r = derive(zone.seed, "tower-look", t.tower_id)
    return float(r.uniform(lo, hi)), float(np.exp(r.uniform(np.log(ilo), np.log(ihi))))


def _green_lookup(zone: Zone, b, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Grass/soil blend of the orthophoto (smooth field on a 4 m grid)."""
    res = 4.0
    nx = int(np.ceil((b[2] - b[0]) / res)) + 1
    ny = int(np.ceil((b[3] - b[1]) / res)) + 1
    gx, gy = np.meshgrid(b[0] + np.arange(nx) * res, b[1] + np.arange(ny) * res)
    g = np.clip(0.45 + 0.7 * zone.greenness(gx, gy), 0, 1).ravel()
    ix = np.clip(((x - b[0]) / res).astype(np.int64), 0, nx - 1)
    iy = np.clip(((y - b[1]) / res).astype(np.int64), 0, ny - 1)
    return g[iy * nx + ix]
