"""Zones on real background tiles: real airborne blocks with towers and conductors inserted.

Each background tile (IGN LiDAR HD in ``../shared/data/real/backgrounds``) keeps its
points, classes and CRS. Towers — real shapes of chosen families or synthetic designs —
stand on its real ground away from buildings, at a density of their own; with ``lines``
they stand along a straight line across the tile and carry conductors (catenaries from
each tower to the next and out of the tile on both sides, as a corridor crossing it).
A tile can be used several times (``copies``), each copy moved 3 km east with towers of
its own, so that one small background holds enough towers for a benchmark. ``cranes``
puts tower cranes beside the lines (hard negatives that the conductors pass near).

Inserted points take their attributes as a colourised flight gives them, and ``variant`` then
degrades the whole zone as public data sets often are (:mod:`towerpipe.synth.delivery`).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import geopandas as gpd
import laspy
import numpy as np
import shapely
from scipy.spatial import cKDTree

from towerpipe import classes
from towerpipe.errors import ConfigError, InputError
from towerpipe.synth import color as col
from towerpipe.synth.delivery import SOURCE_GROUND, VARIANTS, degrade, drop_source_ground, with_attributes
from towerpipe.synth.lasout import write_block
from towerpipe.synth.negatives import crane_beside_line
from towerpipe.synth.params import SceneParams
from towerpipe.synth.primitives import sample_segments, segments
from towerpipe.synth.real import RealTowerLibrary, attachments, realise, to_world
from towerpipe.synth.rng import derive
from towerpipe.synth.towers import DESIGNS, HEIGHTS, WOODEN, place_tower
from towerpipe.synth.truth import META_JSON, TRUTH_COLUMNS, ZoneTruth, write_truth
from towerpipe.synth.wires import catenary

log = logging.getLogger(__name__)

#: East shift (m) between copies of a background tile.
COPY_SPACING = 3000.0
#: Span (m) to a line's next tower, and the gap between parallel lines across a tile.
LINE_SPAN, LINE_GAP = (250.0, 380.0), (60.0, 95.0)
#: Towers keep this distance (m) from the tile edge and from buildings.
EDGE_MARGIN, BUILDING_MARGIN = 15.0, 12.0
#: A tower stands where the tile has a ground point closer than this (m).
GROUND_GAP = 2.0


def ground_fn(xyz: np.ndarray, cls: np.ndarray):
    """Ground elevation function from the real ground points (mean of 6 nearest)."""
    g = xyz[cls == 2]
    if len(g) < 10:
        g = xyz[xyz[:, 2] <= np.quantile(xyz[:, 2], 0.1)]
    tree = cKDTree(g[:, :2])

    def z(x, y):
        _, i = tree.query(np.c_[np.asarray(x, float), np.asarray(y, float)], k=min(6, len(g)))
        return g[i, 2].mean(axis=1)

    return z


def _tile_files(backgrounds: str | Path, files: list[str] | None) -> list[Path]:
    root = Path(backgrounds)
    paths = sorted(root.glob("*.la[sz]")) if root.is_dir() else [root]
    if files:
        missing = sorted(set(files) - {p.name for p in paths})
        if missing:
            raise InputError(root, f"background tiles {missing} not found")
        paths = [p for p in paths if p.name in files]
    if not paths:
        raise InputError(root, "no *.las / *.laz background tile found")
    return paths


def _stations(
    rng: np.random.Generator, box: tuple[float, float, float, float], n_range: tuple[int, int], lines: bool, clear
) -> tuple[np.ndarray, np.ndarray]:
    """Tower positions in a tile and the heading of the line through each.

    With ``lines``, parallel lines :data:`LINE_GAP` apart cross the tile at one heading and
    each has one tower in it (its neighbours stand one span away, outside the tile): the
    towers of one line are of one type, and so are these.
    """
    xmin, ymin, xmax, ymax = box
    lo = np.array([xmin + EDGE_MARGIN, ymin + EDGE_MARGIN])
    hi = np.array([xmax - EDGE_MARGIN, ymax - EDGE_MARGIN])
    if np.any(hi <= lo):  # a small tile: its centre
        c = np.array([(xmin + xmax) / 2, (ymin + ymax) / 2])
        return c[None, :], np.array([rng.uniform(0, np.pi)])
    if not lines:
        pts = []
        for _ in range(int(rng.integers(n_range[0], n_range[1] + 1))):
            for _ in range(100):
                p = rng.uniform(lo, hi)
                if clear(p):
                    pts.append(p)
                    break
        return np.array(pts).reshape(-1, 2), rng.uniform(0, np.pi, len(pts))
    heading = float(rng.uniform(0, np.pi))
    d, nrm = np.array([np.cos(heading), np.sin(heading)]), np.array([-np.sin(heading), np.cos(heading)])
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]])
    across, along = corners @ nrm, corners @ d
    pts = []
    off = across.min() + rng.uniform(0.2, 0.8) * min(LINE_GAP[0], np.ptp(across))
    while off < across.max():
        for _ in range(100):  # a spot on this line inside the tile
            p = off * nrm + rng.uniform(along.min(), along.max()) * d
            if np.all((p >= lo) & (p <= hi)) and clear(p):
                pts.append(p)
                break
        off += rng.uniform(*LINE_GAP)
    return np.array(pts).reshape(-1, 2), np.full(len(pts), heading)


def generate_background_zone(
    out: Path,
    *,
    seed: int,
    backgrounds: str | Path,
    tower_source: str,
    real_towers: str | Path | None,
    params: SceneParams,
    tower_families: list[str] | None = None,
    files: list[str] | None = None,
    copies: int = 1,
    towers_per_tile: tuple[int, int] = (1, 2),
    tower_density: tuple[float, float] | None = None,
    tower_height: tuple[float, float] | None = None,
    lines: bool = False,
    variant: str | list[str] = "intact",
    cranes: int = 0,
) -> ZoneTruth:
    """Insert towers into the real background tiles of ``backgrounds`` (see the module docstring).

    Parameters
    ----------
    out
        Output directory; blocks are named by their lower-left corner.
    seed
        Random seed.
    backgrounds
        A directory of ``*.las`` / ``*.laz`` tiles, or one tile.
    tower_source
        ``synthetic`` (generator designs), ``real`` (real shapes) or ``mixed`` (half each).
    real_towers, tower_families
        The real tower directory and the families drawn from (``None``: all).
    params
        Scene parameters (tower colour, intensity and visibility, wire width).
    files
        Names of the tiles to use (default: all).
    copies
        Copies of each tile, each moved :data:`COPY_SPACING` east with its own towers.
    towers_per_tile
        Range of the number of towers per tile without ``lines``.
    tower_density
        Range (pts/m²) of each tower's own density; ``None``: the tile's density.
    tower_height
        Range (m) each real shape is scaled to; ``None``: its own height within 10 %.
    lines
        Towers on parallel lines across each tile, with conductors.
    variant
        One of :data:`VARIANTS`, or a list of them (degraded in every way listed).
    cranes
        Tower cranes per tile copy, each beside a line of the tile
        (:func:`towerpipe.synth.negatives.crane_beside_line`; recorded in the metadata's ``negatives``).
    """
    variants = [variant] if isinstance(variant, str) else list(variant)
    if not variants or set(variants) - set(VARIANTS):
        raise ConfigError(f"synth variant {variant!r} unknown; choose one (or a list) of {list(VARIANTS)}")
    if copies < 1:
        raise ConfigError("synth copies must be >= 1")
    paths = _tile_files(backgrounds, files)
    lib = RealTowerLibrary(real_towers, tower_families) if tower_source != "synthetic" else None
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    blocks, spans, negatives = [], [], []
    crs_out = None
    next_id = 1
    for copy in range(copies):
        for f in paths:
            rng = derive(seed, "background", f.name, copy)
            las = laspy.read(f)
            crs = las.header.parse_crs()
            crs_out = crs_out or crs
            ins = _insert(
                las,
                rng,
                copy * COPY_SPACING,
                next_id,
                lib=lib,
                tower_source=tower_source,
                params=params,
                towers_per_tile=towers_per_tile,
                tower_density=tower_density,
                tower_height=tower_height,
                lines=lines,
                cranes=cranes,
            )
            negatives += ins["negatives"]
            next_id += len(ins["rows"])
            rows += ins["rows"]
            spans += ins["spans"]
            pts = ins["points"]
            for v in variants:
                pts = degrade(pts, v)
            name = ins["name"]
            path = out / f"{name}.laz"
            # one CRS for the zone: tiles of one system can carry differently written WKTs
            write_block(
                path,
                pts,
                crs_out if crs_out is not None else "EPSG:2154",
                point_format=6 if "no_colour" in variants else 8,
            )
            for r in ins["rows"]:
                r["block"] = r["blocks"] = name
            n_pts, bounds = int(len(pts["x"])), ins["bounds"]
            blocks.append(
                {"name": name, "path": str(path), "source": str(f), "copy": copy, "n_points": n_pts, "bounds": bounds}
            )
            log.info("background block %s (%s, copy %d): %d towers", name, f.name, copy, len(ins["rows"]))
    gdf = gpd.GeoDataFrame(rows, columns=TRUTH_COLUMNS, geometry="geometry", crs=crs_out)
    write_truth(out, gdf)
    meta = {
        "seed": seed,
        "backgrounds": str(backgrounds),
        "files": [p.name for p in paths],
        "copies": copies,
        "tower_source": tower_source,
        "tower_families": tower_families,
        "tower_density": tower_density,
        "tower_height": tower_height,
        "lines": lines,
        "variant": variant,
        "blocks": blocks,
        "params": params.to_dict(),
        "spans": spans,
        "negatives": negatives,
    }
    (out / META_JSON).write_text(json.dumps(meta, indent=1))
    return ZoneTruth(out, blocks, gdf, np.array(spans, np.int64).reshape(-1, 2), meta)


def _insert(
    las: laspy.LasData,
    rng: np.random.Generator,
    dx: float,
    first_id: int,
    *,
    lib,
    tower_source: str,
    params: SceneParams,
    towers_per_tile,
    tower_density,
    tower_height: tuple[float, float] | None = None,
    lines: bool,
    cranes: int = 0,
) -> dict:
    """One tile (moved ``dx`` east) with its towers, conductors and cranes: points, truth rows,
    spans, negatives."""
    from towerpipe.synth.scene import block_name

    xyz = np.c_[np.asarray(las.x) + dx, las.y, las.z]
    cls = np.asarray(las.classification).astype(np.uint8)
    n0 = len(xyz)
    xmin, ymin = xyz[:, :2].min(axis=0)
    xmax, ymax = xyz[:, :2].max(axis=0)
    tile_density = n0 / max((xmax - xmin) * (ymax - ymin), 1.0)
    gz = ground_fn(xyz, cls)
    bld = xyz[cls == 6, :2]
    btree = cKDTree(bld) if len(bld) else None
    gtree = cKDTree(xyz[cls == 2, :2]) if (cls == 2).any() else cKDTree(xyz[:, :2])

    def box(p: np.ndarray) -> np.ndarray:
        return (p[:, 0] >= xmin) & (p[:, 0] <= xmax) & (p[:, 1] >= ymin) & (p[:, 1] <= ymax)

    def in_box(p: np.ndarray) -> np.ndarray:
        return p[box(p)]

    def clear(p):
        """Away from buildings, and on ground the tile has data of (a tile's box can be mostly empty)."""
        return (btree is None or btree.query(p)[0] > BUILDING_MARGIN) and gtree.query(p)[0] < GROUND_GAP

    where, heading = _stations(rng, (xmin, ymin, xmax, ymax), towers_per_tile, lines, clear)
    towers = []  # (id, design, height, base, world points, attachments, material, ground layer)
    wires: list[np.ndarray] = []
    for p, head in zip(where, heading):
        rot = head - np.pi / 2  # local x across the line
        dens = float(rng.uniform(*tower_density)) if tower_density else tile_density
        base_z = float(gz(p[:1], p[1:])[0])
        if lib is not None and (tower_source == "real" or rng.random() < 0.5):
            name, shape = lib.draw(rng)
            own = np.ptp(shape[:, 2]) * rng.uniform(0.9, 1.1)
            h = float(np.clip(rng.uniform(*tower_height) if tower_height else own, 10.0, 60.0))
            local, index = realise(shape, h, dens, rng, params)
            if len(local) < 5:  # a thin pole at a low density: nothing to see
                continue
            pts = to_world(local, p[0], p[1], base_z, rot)
            ground = lib.ground(name, index)
            att = to_world(attachments(local), p[0], p[1], base_z, rot)
            design, material = f"real:{name}", col.STEEL
        else:
            design = str(rng.choice(DESIGNS))
            h = float(np.clip(rng.uniform(*HEIGHTS[design]), 10.0, 60.0))
            t = place_tower(0, design, p[0], p[1], rot, h, gz, rng)
            pts, _ = sample_segments(t.prim, dens, rng, beam=params.member_beam, vertical_factor=params.vertical_factor)
            zrel = np.clip((pts[:, 2] - t.base_z) / h, 0, 1)
            vis = params.tower_visibility_min + (1 - params.tower_visibility_min) * zrel**0.6
            pts = pts[rng.random(len(pts)) < vis]
            att = t.attach
            material = col.WOOD if design in WOODEN else col.STEEL
            ground = np.zeros(len(pts), bool)
        inside = box(pts)
        pts, ground = pts[inside], ground[inside]
        if len(pts) >= 5:
            towers.append((first_id + len(towers), design, h, base_z, pts, _three(att, head), material, ground))
            if lines:
                wires.append(_conductors(towers[-1][5], head, float(rng.uniform(*LINE_SPAN)), gz, tile_density, rng))
    parts, rows = [], []
    for tid, design, h, base_z, pts, _, material, ground in towers:
        own_share = float(rng.uniform(*params.tower_own_color))
        factor = float(np.exp(rng.uniform(*np.log(params.tower_intensity))))
        parts.append(
            (pts, np.where(ground, SOURCE_GROUND, classes.TOWER), np.where(ground, 0, tid), material, own_share, factor)
        )
        n_own = int((~ground).sum())
        pts = pts[~ground] if n_own else pts  # the truth is the tower's own points
        fp = shapely.convex_hull(shapely.MultiPoint(pts[:, :2])).buffer(0.25, quad_segs=2)
        base = pts[pts[:, 2] < base_z + 0.1 * h]
        rows.append(
            {
                "tower_id": tid,
                "design": design,
                "height": round(h, 3),
                "base_z": round(base_z, 3),
                "base_width": round(float(np.ptp(base[:, 0])) if len(base) else 1.0, 3),
                "x": float(np.median(base[:, 0])) if len(base) else float(pts[:, 0].mean()),
                "y": float(np.median(base[:, 1])) if len(base) else float(pts[:, 1].mean()),
                "centroid_x": fp.centroid.x,
                "centroid_y": fp.centroid.y,
                "n_points": n_own,
                "block": None,
                "blocks": None,
                "line_id": tid if lines else 0,
                "geometry": fp,
            }
        )
    if wires:
        klass = classes.WIRE_CONDUCTOR if params.wire_class else classes.OTHER
        parts.append((in_box(np.concatenate(wires)), klass, 0, col.WIRE, 0.3, 1.0))
    negatives = []
    for _ in range(cranes if len(where) else 0):
        k = int(rng.integers(len(where)))
        neg = crane_beside_line(rng, where[k], float(heading[k]), gz, clear)
        if neg is not None:
            dens = float(rng.uniform(*tower_density)) if tower_density else tile_density
            c, _ = sample_segments(neg.prim, dens, rng, beam=params.member_beam, vertical_factor=params.vertical_factor)
            parts.append((in_box(c), classes.OTHER, 0, col.STEEL, 0.7, 1.0))
            negatives.append({"kind": neg.kind, "x": neg.x, "y": neg.y, "height": round(neg.height, 3)})
    points = drop_source_ground(with_attributes(las, xyz, cls, parts, rng))
    return {
        "points": points,
        "rows": rows,
        "name": block_name(np.floor(xmin), np.floor(ymin)),
        "bounds": [float(xmin), float(ymin), float(xmax), float(ymax)],
        "spans": [],
        "negatives": negatives,
    }


def _three(att: np.ndarray, heading: float) -> np.ndarray:
    """The outermost attachment on each side across the line and the highest one (3, 3)."""
    across = att[:, :2] @ np.array([-np.sin(heading), np.cos(heading)])
    return att[[int(np.argmin(across)), int(np.argmax(across)), int(np.argmax(att[:, 2]))]]


def _conductors(
    att: np.ndarray, heading: float, span: float, gz, density: float, rng: np.random.Generator
) -> np.ndarray:
    """Wire points of one tower's line: catenaries to the next tower on each side, one span away."""
    d = np.array([np.cos(heading), np.sin(heading), 0.0])
    chain = []
    for sign in (-1.0, 0.0, 1.0):
        moved = att + sign * span * d
        moved[:, 2] += float(gz(moved[-1:, 0], moved[-1:, 1])[0]) - float(gz(att[-1:, 0], att[-1:, 1])[0])
        chain.append(moved)
    param = float(rng.uniform(900.0, 2200.0))
    segs = []
    for a, b in zip(chain[:-1], chain[1:]):
        for pa, pb in zip(a, b):
            c = catenary(pa, pb, param)
            segs.append(np.stack([c[:-1], c[1:]], axis=1))
    pts, _ = sample_segments(segments(np.concatenate(segs), 0.12), density, rng, beam=0.0, vertical_factor=0.25)
    return pts
