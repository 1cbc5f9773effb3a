"""Real shapes and backgrounds: real tower point sets resampled to airborne density,
and towers inserted into real background tiles.

Tower sources (a directory laid out as ``../shared/data/real/towers``):
``uav_towers/NNNTower.txt`` (doubled points deduplicated), ``ts40k/*.npy`` (class 15,
largest cluster), ``utility_structures/*.las`` (split into structures by clustering;
US-survey-feet files converted to metres). The package holds none of these files.
"""

from __future__ import annotations

import logging
from pathlib import Path

import laspy
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from towerpipe.errors import InputError
from towerpipe.synth.params import SceneParams
from towerpipe.synth.primitives import Primitives
from towerpipe.synth.towers import Tower

log = logging.getLogger(__name__)
US_FOOT = 1200.0 / 3937.0


def clusters(xyz: np.ndarray, radius: float = 1.5, voxel: float = 0.5) -> np.ndarray:
    """Connected-component labels of points (links shorter than ``radius``)."""
    key = np.floor(xyz / voxel).astype(np.int64)
    uk, inv = np.unique(key, axis=0, return_inverse=True)
    cent = (uk + 0.5) * voxel
    pairs = cKDTree(cent).query_pairs(radius, output_type="ndarray")
    n = len(uk)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    return lab[inv.ravel()]


def _normalise(xyz: np.ndarray) -> np.ndarray:
    """Centre on the base (xy mean of the lowest 20 %), base at z = 0, major axis along x."""
    xyz = np.asarray(xyz, float)
    z0 = xyz[:, 2].min()
    low = xyz[xyz[:, 2] < z0 + 0.2 * (xyz[:, 2].max() - z0)]
    c = low[:, :2].mean(axis=0)
    out = np.c_[xyz[:, :2] - c, xyz[:, 2] - z0]
    cov = np.cov(out[:, :2].T)
    w, v = np.linalg.eigh(cov)
    a = np.arctan2(v[1, 1], v[0, 1])                    # major axis angle
    ca, sa = np.cos(-a), np.sin(-a)
    return np.c_[ca * out[:, 0] - sa * out[:, 1], sa * out[:, 0] + ca * out[:, 1], out[:, 2]]


def load_real_towers(root: str | Path) -> list[tuple[str, np.ndarray]]:
    """All real tower point sets (name, normalised xyz in metres) under ``root``."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "real tower directory not found (expected ../shared/data/real/towers)")
    out = []
    for f in sorted((root / "uav_towers").glob("*Tower.txt")):
        xyz = np.unique(np.loadtxt(f, delimiter=","), axis=0)
        out.append((f"uav:{f.stem}", _normalise(xyz)))
    for f in sorted((root / "ts40k").glob("*.npy")):
        a = np.load(f)
        xyz = a[a[:, 3] == 15, :3]
        if len(xyz) < 50:
            continue
        lab = clusters(xyz)
        big = np.bincount(lab).argmax()
        out.append((f"ts40k:{f.stem}", _normalise(xyz[lab == big])))
    for f in sorted((root / "utility_structures").glob("*.las")):
        las = laspy.read(f)
        xyz = np.c_[las.x, las.y, las.z]
        crs = las.header.parse_crs()
        feet = (crs is not None and "foot" in crs.axis_info[0].unit_name.lower()) or \
            (crs is None and np.ptp(xyz[:, 2]) > 100)
        if feet:
            xyz = xyz * US_FOOT
        lab = clusters(xyz, radius=2.0, voxel=0.6)
        for k in np.flatnonzero(np.bincount(lab) >= 40):
            s = xyz[lab == k]
            h = np.ptp(s[:, 2])
            if 8.0 <= h <= 70.0 and np.ptp(s[:, 0]) < 30 and np.ptp(s[:, 1]) < 30:
                out.append((f"utility:{f.stem}:{k}", _normalise(s)))
    if not out:
        raise InputError(root, "no real tower point set found (uav_towers/, ts40k/, utility_structures/)")
    return out


def airborne_resample(xyz: np.ndarray, density: float, rng: np.random.Generator, *,
                      vertical_factor: float = 0.25, vis_min: float = 0.3, voxel: float = 0.15) -> np.ndarray:
    """Thin a dense tower point set to what an airborne scanner at ``density`` sees.

    Voxel thinning removes the UAV over-sampling; the expected count is
    density × projected metal area × (1 + vertical factor), the metal area being
    estimated from the occupied 0.2 m cells of the xy projection; points are
    kept with a probability that grows with height (occlusion of the lower part).
    """
    key = np.floor(xyz / voxel).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    v = xyz[np.sort(first)]
    cells = np.unique(np.floor(v[:, :2] / 0.2).astype(np.int64), axis=0)
    area = len(cells) * 0.04 * 0.5
    n_target = density * area * (1 + vertical_factor)
    zrel = np.clip(v[:, 2] / max(np.ptp(v[:, 2]), 1e-6), 0, 1)
    w = vis_min + (1 - vis_min) * zrel ** 0.6
    p = np.clip(n_target * w / w.sum(), 0, 1)
    return v[rng.random(len(v)) < p]


class RealTowerLibrary:
    """Real tower shapes that replace synthetic towers of a zone."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.items = load_real_towers(self.root)
        # One family per source (uav, ts40k, utility), drawn with equal chance: the 99
        # airborne utility poles would otherwise make three real towers in four poles.
        by_source: dict[str, list[tuple[str, np.ndarray]]] = {}
        for item in self.items:
            by_source.setdefault(item[0].split(":")[0], []).append(item)
        self.families = [by_source[k] for k in sorted(by_source)]

    def factory(self, density: float, params: SceneParams, share: float = 1.0):
        """A ``(tower, rng) -> tower`` callable for :func:`towerpipe.synth.scene.build_zone`."""
        def make(t: Tower, rng: np.random.Generator) -> Tower:
            if rng.random() >= share:
                return t
            family = self.families[int(rng.integers(len(self.families)))]
            name, shape = family[int(rng.integers(len(family)))]
            h = float(np.clip(t.height, 10.0, 50.0))
            s = shape * (h / max(np.ptp(shape[:, 2]), 1e-6))
            if rng.random() < 0.5:
                s[:, 0] = -s[:, 0]
            pts = airborne_resample(s, density, rng, vertical_factor=params.vertical_factor,
                                    vis_min=params.tower_visibility_min)
            c, si = np.cos(t.rot), np.sin(t.rot)
            world = np.c_[t.x + c * pts[:, 0] - si * pts[:, 1], t.y + si * pts[:, 0] + c * pts[:, 1],
                          t.base_z + pts[:, 2]]
            base = s[s[:, 2] < 0.1 * h]
            bw = float(np.ptp(base[:, 0])) if len(base) else 1.0
            return Tower(t.tower_id, f"real:{name}", t.x, t.y, t.base_z, h, t.rot, Primitives.empty(),
                         t.attach, bw, points=world, line_id=t.line_id)
        return make


def finalize_real_towers(zone) -> None:
    """Drop real towers that ended up without points (nothing else to do)."""
    zone.lines.towers = [t for t in zone.lines.towers if t.points is None or len(t.points)]


def _ground_fn(las_xyz: np.ndarray, cls: np.ndarray):
    """Ground elevation function from the real ground points (mean of 6 nearest)."""
    g = las_xyz[cls == 2]
    if len(g) < 10:
        g = las_xyz[las_xyz[:, 2] <= np.quantile(las_xyz[:, 2], 0.1)]
    tree = cKDTree(g[:, :2])

    def z(x, y):
        _, i = tree.query(np.c_[np.asarray(x, float), np.asarray(y, float)], k=min(6, len(g)))
        return g[i, 2].mean(axis=1)
    return z


def generate_real_background_zone(out: Path, *, seed: int, backgrounds: str | Path, tower_source: str,
                                  real_towers: str | Path | None, params: SceneParams,
                                  towers_per_tile: tuple[int, int] = (1, 2)):
    """Insert towers into every real background tile of ``backgrounds``.

    Each tile keeps its points, classes and CRS (EPSG:2154 for the IGN tiles);
    1-2 towers (synthetic designs or real shapes, resampled to the tile's density)
    are placed on the real ground away from buildings, coloured as steel; tiles
    without NIR get a synthetic NIR (high on vegetation classes, ≈ red elsewhere).
    Output files are named by their lower-left corner; the truth sidecar as usual.
    """
    import geopandas as gpd

    from towerpipe.synth import color as col
    from towerpipe.synth.lasout import write_block
    from towerpipe.synth.primitives import sample_segments
    from towerpipe.synth.rng import derive
    from towerpipe.synth.scene import block_name
    from towerpipe.synth.towers import DESIGNS, HEIGHTS, place_tower
    from towerpipe.synth.zone import META_JSON, ZoneTruth, write_truth
    import json

    files = sorted(Path(backgrounds).glob("*.la[sz]"))
    if not files:
        raise InputError(backgrounds, "no *.las / *.laz background tile found")
    lib = RealTowerLibrary(real_towers) if tower_source != "synthetic" else None
    out.mkdir(parents=True, exist_ok=True)
    rows, blocks, next_id, crs_out = [], [], 1, None
    for fi, f in enumerate(files):
        rng = derive(seed, "background", f.name)
        las = laspy.read(f)
        crs = las.header.parse_crs()
        crs_out = crs_out or crs
        xyz = np.c_[las.x, las.y, las.z]
        cls = np.asarray(las.classification).astype(np.uint8)
        n0 = len(xyz)
        xmin, ymin = xyz[:, :2].min(axis=0)
        xmax, ymax = xyz[:, :2].max(axis=0)
        density = n0 / max((xmax - xmin) * (ymax - ymin), 1.0)
        gz = _ground_fn(xyz, cls)
        bld = xyz[cls == 6, :2]
        btree = cKDTree(bld) if len(bld) else None
        new_pts, new_id = [], []
        for k in range(int(rng.integers(towers_per_tile[0], towers_per_tile[1] + 1))):
            for _ in range(30):       # find a spot away from buildings and the tile edge
                x, y = rng.uniform(xmin + 15, xmax - 15), rng.uniform(ymin + 15, ymax - 15)
                if xmax - xmin < 30 or ymax - ymin < 30:
                    x, y = (xmin + xmax) / 2, (ymin + ymax) / 2
                if btree is None or btree.query([x, y])[0] > 12:
                    break
            design = str(rng.choice(DESIGNS))
            h = float(np.clip(rng.uniform(*HEIGHTS[design]), 10, 50))
            t = place_tower(next_id, design, x, y, rng.uniform(0, np.pi), h, gz, rng)
            if lib is not None and (tower_source == "real" or rng.random() < 0.5):
                t = lib.factory(density, params)(t, rng)
                pts = t.points
            else:
                pts, _ = sample_segments(t.prim, density, rng, beam=params.member_beam,
                                         vertical_factor=params.vertical_factor)
                zrel = np.clip((pts[:, 2] - t.base_z) / h, 0, 1)
                vis = params.tower_visibility_min + (1 - params.tower_visibility_min) * zrel ** 0.6
                pts = pts[rng.random(len(pts)) < vis]
            inside = (pts[:, 0] >= xmin) & (pts[:, 0] <= xmax) & (pts[:, 1] >= ymin) & (pts[:, 1] <= ymax)
            pts = pts[inside]
            if len(pts) < 5:           # fell outside a small tile: not a tower of this tile
                continue
            new_pts.append(pts)
            new_id.append(np.full(len(pts), next_id, np.uint32))
            fp = t.outline()
            rows.append({"tower_id": next_id, "design": t.design, "height": round(h, 3),
                         "base_z": round(t.base_z, 3), "base_width": round(t.base_width, 3), "x": t.x, "y": t.y,
                         "centroid_x": fp.centroid.x, "centroid_y": fp.centroid.y, "n_points": int(len(pts)),
                         "block": None, "blocks": None, "line_id": 0, "geometry": fp})
            next_id += 1
        add = np.concatenate(new_pts) if new_pts else np.zeros((0, 3))
        m = len(add)
        dims = las.point_format.dimension_names
        def get(name, default):
            return np.asarray(las[name]) if name in dims else default
        red = get("red", None)
        has_rgb = red is not None and np.asarray(red).max() > 0
        if has_rgb:
            r8, g8, b8 = (np.asarray(las[c]).astype(np.float32) / 65535 for c in ("red", "green", "blue"))
            if max(r8.max(), g8.max()) <= 255 / 65535:          # 8-bit colour stored raw
                r8, g8, b8 = r8 * 257, g8 * 257, b8 * 257
        else:   # synthetic orthophoto colour from the classes
            mat = np.select([np.isin(cls, [3, 4, 5]), cls == 6], [col.TREE, col.ROOF], col.GROUND)
            c = col.colors(mat, np.arange(n0) // 50, np.full(n0, 0.5), rng)
            r8, g8, b8 = c[:, 0], c[:, 1], c[:, 2]
        nir = get("nir", None)
        if nir is None or np.asarray(nir).max() == 0:
            veg = np.isin(cls, [3, 4, 5])
            nirf = np.where(veg, np.clip(0.35 + 1.6 * g8, 0, 1), np.clip(r8 * 0.95, 0, 1))
        else:
            nirf = np.asarray(nir).astype(np.float32) / 65535
        steel = col.colors(np.full(m, col.STEEL), np.zeros(m, int), np.zeros(m), rng)
        name = block_name(np.floor(xmin), np.floor(ymin))
        sa = get("scan_angle", np.zeros(n0)) * (0.006 if las.point_format.id >= 6 else 1.0)
        inten = get("intensity", np.zeros(n0, np.uint16))
        pts = {
            "x": np.r_[xyz[:, 0], add[:, 0]], "y": np.r_[xyz[:, 1], add[:, 1]], "z": np.r_[xyz[:, 2], add[:, 2]],
            "classification": np.r_[cls, np.full(m, 15, np.uint8)],
            "tower_id": np.r_[np.zeros(n0, np.uint32), np.concatenate(new_id) if new_id else []].astype(np.uint32),
            "return_number": np.r_[get("return_number", np.ones(n0)), np.ones(m)].astype(np.uint8),
            "number_of_returns": np.r_[get("number_of_returns", np.ones(n0)), np.full(m, 2)].astype(np.uint8),
            "intensity": np.r_[inten, col.intensity(np.full(m, col.STEEL), np.ones(m), np.full(m, 2), rng)].astype(np.uint16),
            "red": col.to16(np.r_[r8, steel[:, 0]]), "green": col.to16(np.r_[g8, steel[:, 1]]),
            "blue": col.to16(np.r_[b8, steel[:, 2]]), "nir": col.to16(np.r_[nirf, steel[:, 3]]),
            "point_source_id": np.r_[get("point_source_id", np.zeros(n0)), np.zeros(m)].astype(np.uint16),
            "scan_angle": np.r_[sa, np.zeros(m)].astype(np.float32),
            "gps_time": np.r_[get("gps_time", np.zeros(n0)), np.zeros(m)].astype(np.float64),
        }
        path = out / f"{name}.laz"
        write_block(path, pts, crs if crs is not None else "EPSG:2154")
        for r_ in rows:
            if r_["block"] is None:
                r_["block"] = r_["blocks"] = name
        blocks.append({"name": name, "path": str(path), "source": str(f), "n_points": int(n0 + m),
                       "bounds": [float(xmin), float(ymin), float(xmax), float(ymax)]})
    gdf = gpd.GeoDataFrame(rows, geometry="geometry", crs=crs_out)
    write_truth(out, gdf)
    meta = {"seed": seed, "backgrounds": str(backgrounds), "tower_source": tower_source, "blocks": blocks,
            "params": params.to_dict(), "spans": []}
    (out / META_JSON).write_text(json.dumps(meta, indent=1))
    return ZoneTruth(out, blocks, gdf, np.zeros((0, 2), np.int64), meta)
