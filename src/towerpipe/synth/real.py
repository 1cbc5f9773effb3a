"""Real tower shapes: real tower point sets resampled to what an airborne flight sees.

Tower sources (a directory laid out as ``../shared/data/real/towers``):
``uav_towers/NNNTower.txt`` (doubled points deduplicated), ``ts40k/*.npy`` (class 15,
largest cluster), ``utility_structures/*.las`` (split into structures by clustering;
US-survey-feet files converted to metres). The package holds none of these files.

Some sources label the ground and foundations within a tower's footprint as tower: a filled
layer at the base of the set, level (:func:`ground_layer_top`) or sloping (:func:`ground_layer`).
Its points are never the tower's: no airborne product reports the ground under a tower as
tower. A zone draws their attributes and then leaves them out
(:data:`towerpipe.synth.delivery.SOURCE_GROUND`): the zone has its own ground there, over which the
source's would hover.
"""

from __future__ import annotations

import logging
from pathlib import Path

import laspy
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from towerpipe.errors import InputError
from towerpipe.synth.params import SceneParams
from towerpipe.synth.primitives import Primitives
from towerpipe.synth.towers import Tower

log = logging.getLogger(__name__)
US_FOOT = 1200.0 / 3937.0
#: A real tower set's ground layer (:func:`ground_layer_top`): its points lower than ``DEPTH`` m over
#: its lowest point, judged in plan cells of ``CELL`` m, are ground when they fill at least ``FILL``
#: of their convex hull and the hull covers ``AREA`` m² or more; 0.25 m slices above, up to ``MAX``
#: m, belong to it while their points fill half of that hull.
GROUND_LAYER = {"DEPTH": 1.0, "CELL": 0.25, "FILL": 0.75, "AREA": 2.0, "MAX": 2.0}
#: A real tower set's sloping ground layer (:func:`ground_layer`, where no level one is found): the
#: points of its lowest ``LOW`` m within ``THICK`` m of a plane fitted to them, at most ``SLOPE``
#: degrees steep, that fill ``GROUND_LAYER["FILL"]`` of a hull of ``GROUND_LAYER["AREA"]`` m² or
#: more, ``WIDER`` times or more the plan of the body above (the median hull of its 1 m slices from
#: ``LOW`` m to half its height); the points under that plane go with it, and the 0.25 m bands
#: over it whose points still spread over half of that hull.
SLOPED_LAYER = {"LOW": 3.0, "THICK": 0.4, "SLOPE": 30.0, "WIDER": 4.0}


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
    a = np.arctan2(v[1, 1], v[0, 1])  # major axis angle
    ca, sa = np.cos(-a), np.sin(-a)
    return np.c_[ca * out[:, 0] - sa * out[:, 1], sa * out[:, 0] + ca * out[:, 1], out[:, 2]]


def _plan_area(xy: np.ndarray, cell: float) -> float:
    """Area (m²) of the plan cells of side ``cell`` that hold a point."""
    return len(np.unique(np.floor(xy / cell).astype(np.int64), axis=0)) * cell * cell if len(xy) else 0.0


def _hull_area(xy: np.ndarray) -> float:
    """Convex hull area of plan points; 0 for fewer than three or collinear ones."""
    try:
        return float(ConvexHull(xy).volume) if len(xy) >= 3 else 0.0
    except QhullError:
        return 0.0


def _filled_hull(xy: np.ndarray) -> float:
    """The hull area of plan points that fill ``GROUND_LAYER["FILL"]`` of a hull of ``GROUND_LAYER["AREA"]``
    m² or more (in cells of ``GROUND_LAYER["CELL"]`` m), else 0: a layer of ground, not legs or a pole's foot."""
    g = GROUND_LAYER
    hull = _hull_area(xy)  # 0 where collinear or coincident: a pole's foot
    return hull if hull >= g["AREA"] and _plan_area(xy, g["CELL"]) >= g["FILL"] * hull else 0.0


def ground_layer_top(xyz: np.ndarray) -> float:
    """Height over a real tower set's lowest point below which its points are ground; 0 where none.

    A lattice's legs and a pole fill little of the plan their lowest metre spans (the 21 UAV
    lattices of ``../shared``: at most 53 %); the ground or a foundation slab that a source labels
    with the tower fills it (four of the eight TS40K sets: 85-100 % of 6-15 m², 27-62 % of their
    points). Such a layer is the lowest ``GROUND_LAYER["DEPTH"]`` m, grown by the 0.25 m slices
    above it that still fill half of its hull (a slab on sloping ground).

    Parameters
    ----------
    xyz
        ``(n, 3)`` points of one real tower set (metres).

    Returns
    -------
    float
        The layer's top over the lowest point (m), or 0.0 when the base is no filled layer.
    """
    g = GROUND_LAYER
    xyz = np.asarray(xyz, float)
    if len(xyz) < 3:
        return 0.0
    z = xyz[:, 2] - xyz[:, 2].min()
    low = xyz[z < g["DEPTH"], :2]
    if len(low) < 3:
        return 0.0
    hull = _filled_hull(low)
    if not hull:
        return 0.0
    top = g["DEPTH"]
    while top < g["MAX"] and _plan_area(xyz[(z >= top) & (z < top + 0.25), :2], g["CELL"]) >= 0.5 * hull:
        top += 0.25
    return float(top)


def _sloped_layer(xyz: np.ndarray) -> np.ndarray:
    """Which points of a real tower set are a sloping ground layer at its base (:data:`SLOPED_LAYER`)."""
    s = SLOPED_LAYER
    z = xyz[:, 2] - xyz[:, 2].min()
    none = np.zeros(len(xyz), bool)
    low = z < s["LOW"]
    fit = low
    a = np.c_[xyz[:, :2], np.ones(len(xyz))]
    for _ in range(5):  # refit on the points near the plane until they stay the same
        if fit.sum() < 10:
            return none
        coef = np.linalg.lstsq(a[fit], z[fit], rcond=None)[0]
        resid = z - a @ coef
        near = (np.abs(resid) < s["THICK"]) & low
        if (near == fit).all():
            break
        fit = near
    hull = _filled_hull(xyz[near, :2])
    if not hull:
        return none
    if np.degrees(np.arctan(np.hypot(*coef[:2]))) > s["SLOPE"]:
        return none
    top = float(z.max())
    body = [
        _hull_area(xyz[(z >= lo) & (z < lo + 1.0), :2]) for lo in np.arange(s["LOW"], max(top / 2, s["LOW"] + 1), 1.0)
    ]
    if hull < s["WIDER"] * float(np.median(body)):
        return none  # a lattice's base bracing: as wide as the body above it
    up = s["THICK"]  # grown by the 0.25 m bands over the plane that still spread over half of its hull
    while _hull_area(xyz[(resid >= up) & (resid < up + 0.25) & low, :2]) >= 0.5 * hull:
        up += 0.25
    return (resid < up) & low


def ground_layer(xyz: np.ndarray) -> np.ndarray:
    """Which points of a real tower set are ground its source labels as tower.

    A level layer (:func:`ground_layer_top`), else a sloping one: ground on a slope, which a
    source's box around the tower cuts as a tilted slab filling a plan several times wider
    than the tower above it (two of the eight TS40K sets; a UAV lattice's base bracing is as wide
    as its body).

    Parameters
    ----------
    xyz
        ``(n, 3)`` points of a real tower set as :func:`load_real_towers` gives them.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` bool, True for the layer's points.
    """
    xyz = np.asarray(xyz, float)
    if len(xyz) < 3:
        return np.zeros(len(xyz), bool)
    top = ground_layer_top(xyz)
    if top > 0:
        return xyz[:, 2] - xyz[:, 2].min() < top
    return _sloped_layer(xyz)


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
        feet = (crs is not None and "foot" in crs.axis_info[0].unit_name.lower()) or (
            crs is None and np.ptp(xyz[:, 2]) > 100
        )
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


def airborne_resample(
    xyz: np.ndarray,
    density: float,
    rng: np.random.Generator,
    *,
    vertical_factor: float = 0.25,
    vis_min: float = 0.3,
    voxel: float = 0.15,
    return_index: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Thin a dense tower point set to what an airborne scanner at ``density`` sees.

    Voxel thinning removes the UAV over-sampling; the expected count is
    density × projected metal area × (1 + vertical factor), the metal area being
    estimated from the occupied 0.2 m cells of the xy projection; points are
    kept with a probability that grows with height (occlusion of the lower part). With
    ``return_index``, also the kept points' indices into ``xyz``.
    """
    key = np.floor(xyz / voxel).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    v = xyz[first]
    cells = np.unique(np.floor(v[:, :2] / 0.2).astype(np.int64), axis=0)
    area = len(cells) * 0.04 * 0.5
    n_target = density * area * (1 + vertical_factor)
    zrel = np.clip(v[:, 2] / max(np.ptp(v[:, 2]), 1e-6), 0, 1)
    w = vis_min + (1 - vis_min) * zrel**0.6
    p = np.clip(n_target * w / w.sum(), 0, 1)
    kept = rng.random(len(v)) < p
    return (v[kept], first[kept]) if return_index else v[kept]


#: The real tower families (sources) of ``../shared/data/real/towers``, by name prefix.
FAMILIES = ("ts40k", "uav", "utility")


def tower_family(design: str) -> str | None:
    """The real family of a truth ``design`` (``"real:uav:001Tower"`` -> ``"uav"``), else ``None``."""
    parts = str(design).split(":")
    return parts[1] if len(parts) > 2 and parts[0] == "real" and parts[1] in FAMILIES else None


class RealTowerLibrary:
    """Real tower shapes that replace synthetic towers of a zone.

    Parameters
    ----------
    root
        Directory laid out as ``../shared/data/real/towers``.
    families
        The families (:data:`FAMILIES`) to draw from; ``None``: all.
    """

    def __init__(self, root: str | Path, families: list[str] | tuple[str, ...] | None = None):
        self.root = Path(root)
        unknown = sorted(set(families or ()) - set(FAMILIES))
        if unknown:
            raise InputError(root, f"unknown real tower families {unknown}; known: {list(FAMILIES)}")
        self.items = [it for it in load_real_towers(self.root) if families is None or it[0].split(":")[0] in families]
        if not self.items:
            raise InputError(root, f"no real tower of the families {families}")
        # One family per source (uav, ts40k, utility), drawn with equal chance: the 99
        # airborne utility poles would otherwise make three real towers in four poles.
        by_source: dict[str, list[tuple[str, np.ndarray]]] = {}
        for item in self.items:
            by_source.setdefault(item[0].split(":")[0], []).append(item)
        self.families = [by_source[k] for k in sorted(by_source)]
        #: name -> :func:`ground_layer` of its normalised shape (which of its points are ground)
        self.ground_layers = {name: ground_layer(shape) for name, shape in self.items}

    def ground(self, name: str, index: np.ndarray) -> np.ndarray:
        """Which points of a :func:`realise` of the shape ``name`` (their ``index`` into it) are its
        ground layer."""
        return self.ground_layers[name][index]

    def draw(self, rng: np.random.Generator) -> tuple[str, np.ndarray]:
        """A shape: a family with equal chance, then one of its shapes (name, normalised xyz)."""
        family = self.families[int(rng.integers(len(self.families)))]
        return family[int(rng.integers(len(family)))]

    def factory(self, density: float, params: SceneParams, share: float = 1.0):
        """A ``(tower, rng) -> tower`` callable for :func:`towerpipe.synth.scene.build_zone`."""

        def make(t: Tower, rng: np.random.Generator) -> Tower:
            if rng.random() >= share:
                return t
            name, shape = self.draw(rng)
            h = float(np.clip(t.height, 10.0, 60.0))
            pts, index = realise(shape, h, density, rng, params)
            world = to_world(pts, t.x, t.y, t.base_z, t.rot)
            ground = self.ground(name, index)
            base = pts[~ground & (pts[:, 2] < 0.1 * h)]
            bw = float(np.ptp(base[:, 0])) if len(base) else 1.0
            return Tower(
                t.tower_id,
                f"real:{name}",
                t.x,
                t.y,
                t.base_z,
                h,
                t.rot,
                Primitives.empty(),
                t.attach,
                bw,
                points=world,
                line_id=t.line_id,
                ground=ground,
            )

        return make


def realise(
    shape: np.ndarray, height: float, density: float, rng: np.random.Generator, params: SceneParams
) -> tuple[np.ndarray, np.ndarray]:
    """A real shape as one airborne flight sees it, in its local frame (base centre at 0).

    Scaled to ``height``, mirrored with chance 1/2, its plan stretched by
    ``params.real_tower_jitter``, then thinned to ``density`` (:func:`airborne_resample`).
    Returns the points and their indices into ``shape``.
    """
    s = shape * (height / max(np.ptp(shape[:, 2]), 1e-6))
    if rng.random() < 0.5:
        s[:, 0] = -s[:, 0]
    if params.real_tower_jitter > 0:  # another tower of the same type: proportions vary
        s[:, :2] *= rng.uniform(1 - params.real_tower_jitter, 1 + params.real_tower_jitter, 2)
    return airborne_resample(
        s, density, rng, vertical_factor=params.vertical_factor, vis_min=params.tower_visibility_min, return_index=True
    )


def to_world(local: np.ndarray, x: float, y: float, base_z: float, rot: float) -> np.ndarray:
    """Local tower coordinates (x across the line) turned by ``rot`` and moved to the base."""
    c, si = np.cos(rot), np.sin(rot)
    return np.c_[x + c * local[:, 0] - si * local[:, 1], y + si * local[:, 0] + c * local[:, 1], base_z + local[:, 2]]


def attachments(local: np.ndarray) -> np.ndarray:
    """Where the conductors of a real shape hang (local frame): its outermost upper points.

    Returns ``(3, 3)``: the insulator ends below the two outermost points of the upper 40 %
    across the line (the crossarm tips; near the axis for a pole), and the top (earth wire).
    """
    h = float(local[:, 2].max())
    top = local[local[:, 2] >= 0.6 * h]
    string = min(2.5, 0.08 * h)
    ends = [top[int(np.argmin(top[:, 0]))], top[int(np.argmax(top[:, 0]))]]
    return np.array([[e[0], 0.0, e[2] - string] for e in ends] + [[0.0, 0.0, h]])


def finalize_real_towers(zone) -> None:
    """Drop real towers that ended up without points (nothing else to do)."""
    zone.lines.towers = [t for t in zone.lines.towers if t.points is None or len(t.points)]
