"""Public entry point: :func:`generate_zone` writes blocks + truth sidecars."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import geopandas as gpd
import numpy as np
import shapely

from towerpipe.errors import ConfigError
from towerpipe.synth.lasout import write_block
from towerpipe.synth.params import SceneParams, with_overrides
from towerpipe.synth.params import preset as get_preset
from towerpipe.synth.scene import Zone, block_name, block_points, build_zone
from towerpipe.synth.truth import META_JSON, TRUTH_COLUMNS, ZoneTruth, write_truth

log = logging.getLogger(__name__)

TERRAIN_NPZ = "terrain.npz"
TOWER_SOURCES = ("synthetic", "real", "mixed")


def generate_zone(
    out_dir: str | Path,
    *,
    seed: int,
    blocks: int = 4,
    size: float = 250.0,
    density: float = 10.0,
    crs: str = "EPSG:25831",
    origin: tuple[float, float] = (400000.0, 4600000.0),
    preset: str = "catalonia",
    params: SceneParams | None = None,
    edge_tower: bool = False,
    tower_source: str = "synthetic",
    real_towers: str | Path | None = None,
    real_backgrounds: str | Path | None = None,
    parallel: bool = False,
    tower_families: list[str] | None = None,
    background_files: list[str] | None = None,
    copies: int = 1,
    tower_density: tuple[float, float] | None = None,
    tower_height: tuple[float, float] | None = None,
    lines: bool = False,
    variant: str = "intact",
    tower_variety: bool = False,
    cranes_beside_lines: int = 0,
    **overrides,
) -> ZoneTruth:
    """Generate a synthetic airborne zone of adjoining LAZ blocks with truth.

    Parameters
    ----------
    out_dir
        Output directory (created); blocks are ``<xmin>_<ymin>.laz``.
    seed
        Random seed; the same seed gives identical files.
    blocks, size
        Number of square blocks and their side (m); laid out as square a grid as possible.
    density
        Requested density of all returns (pts/m²), 6-20 is realistic.
    crs, origin
        CRS of the output and lower-left corner of the zone.
    preset, params, overrides
        Scene parameters: a preset name, or a full :class:`SceneParams`, plus field overrides.
    edge_tower
        Force one tower centred on an inner block edge (needs ``blocks >= 2``).
    tower_source
        "synthetic", "real" (real tower point sets from ``real_towers``) or "mixed".
    real_towers
        Directory laid out as ``../shared/data/real/towers`` (needed unless synthetic).
    real_backgrounds
        Directory of real background ``*.laz`` tiles; when given, towers are inserted
        into those tiles instead of a synthetic zone (see :mod:`towerpipe.synth.background`).
    parallel
        Multi-threaded LAZ compression.
    tower_families
        The real tower families drawn from (:data:`towerpipe.synth.real.FAMILIES`; default all).
    background_files, copies, tower_density, tower_height, lines, variant
        Zones on real backgrounds only: the tiles used, copies of each, the towers' own
        density range (pts/m²), the height range (m) the real shapes are scaled to, towers
        along a line with conductors, and the attribute variant
        (:data:`towerpipe.synth.background.VARIANTS`).
    cranes_beside_lines
        Tower cranes per block (per tile copy on real backgrounds), each beside a line tower of
        the block; blocks without one get none.
    tower_variety
        Apply :data:`towerpipe.synth.params.TOWER_VARIETY` (every design, orthophoto
        colours, per-tower intensity, varied real shapes) before ``overrides``.
    """
    if tower_variety:
        from towerpipe.synth.params import TOWER_VARIETY

        overrides = {**TOWER_VARIETY, **overrides}
    out = Path(out_dir)
    if tower_source not in TOWER_SOURCES:
        raise ConfigError(f"tower_source {tower_source!r} unknown; choose one of {TOWER_SOURCES}")
    if tower_source != "synthetic" and real_towers is None:
        raise ConfigError(f"tower_source={tower_source!r} needs real_towers (e.g. ../shared/data/real/towers)")
    if blocks < 1 or size <= 0 or density <= 0:
        raise ConfigError("synth: blocks, size and density must be positive")
    if real_backgrounds is not None:
        from towerpipe.synth.background import generate_background_zone

        return generate_background_zone(
            out,
            seed=seed,
            backgrounds=real_backgrounds,
            tower_source=tower_source,
            real_towers=real_towers,
            params=params or get_preset(preset, **overrides),
            tower_families=tower_families,
            files=background_files,
            copies=copies,
            lines=lines,
            variant=variant,
            tower_density=tuple(tower_density) if tower_density else None,
            tower_height=tuple(tower_height) if tower_height else None,
            cranes=cranes_beside_lines,
        )
    p = params if params is not None else get_preset(preset)
    p = with_overrides(p, **overrides)
    if cranes_beside_lines:
        p = with_overrides(p, cranes_beside_lines=int(cranes_beside_lines))
    if edge_tower:
        p = with_overrides(p, edge_tower=True)
    factory = None
    if tower_source != "synthetic":
        from towerpipe.synth.real import RealTowerLibrary

        lib = RealTowerLibrary(real_towers, tower_families)
        factory = lib.factory(density, p, share=1.0 if tower_source == "real" else 0.5)
    t0 = time.perf_counter()
    zone = build_zone(seed, blocks=blocks, size=size, density=density, origin=origin, params=p, tower_factory=factory)
    if factory is not None:
        from towerpipe.synth.real import finalize_real_towers

        finalize_real_towers(zone)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    n_tower = {}
    for i, b in enumerate(zone.blocks):
        pts = block_points(zone, i)
        name = block_name(b[0], b[1])
        path = out / f"{name}.laz"
        write_block(path, pts, crs, bounds=b, parallel=parallel)
        ids, cnt = np.unique(pts["tower_id"][pts["tower_id"] > 0], return_counts=True)
        for a, c in zip(ids.tolist(), cnt.tolist()):
            n_tower[a] = n_tower.get(a, 0) + c
        cls, cc = np.unique(pts["classification"], return_counts=True)
        written.append(
            {
                "name": name,
                "path": str(path),
                "bounds": list(b),
                "n_points": int(len(pts["x"])),
                "counts": {int(k): int(v) for k, v in zip(cls, cc)},
            }
        )
        log.info("synth block %s: %d points", name, len(pts["x"]))
    towers = truth_table(zone, n_tower, crs)
    write_truth(out, towers)
    zone.terrain.save(out / TERRAIN_NPZ)
    meta = {
        "seed": seed,
        "density": density,
        "size": size,
        "crs": crs,
        "origin": list(origin),
        "bounds": list(zone.bounds),
        "blocks": written,
        "params": p.to_dict(),
        "tower_source": tower_source,
        "spans": zone.lines.spans.tolist(),
        "stringing": {str(k): v for k, v in sorted(zone.lines.stringing.items())},
        "negatives": [{"kind": n.kind, "x": n.x, "y": n.y, "height": n.height} for n in zone.negatives],
        "seconds": round(time.perf_counter() - t0, 3),
    }
    (out / META_JSON).write_text(json.dumps(meta, indent=1))
    return ZoneTruth(out, written, towers, zone.lines.spans, meta)


def truth_table(zone: Zone, n_points: dict[int, int], crs) -> gpd.GeoDataFrame:
    """Truth rows of the towers that have points."""
    rows = []
    for t in zone.towers:
        fp = t.outline()
        blocks = [block_name(b[0], b[1]) for b in zone.blocks if fp.intersects(shapely.box(*b))]
        home = next(block_name(b[0], b[1]) for b in zone.blocks if b[0] <= t.x < b[2] and b[1] <= t.y < b[3])
        c = fp.centroid
        rows.append(
            {
                "tower_id": t.tower_id,
                "design": t.design,
                "height": round(t.height, 3),
                "base_z": round(t.base_z, 3),
                "base_width": round(t.base_width, 3),
                "x": t.x,
                "y": t.y,
                "centroid_x": c.x,
                "centroid_y": c.y,
                "n_points": int(n_points.get(t.tower_id, 0)),
                "block": home,
                "blocks": ",".join(blocks),
                "line_id": t.line_id,
                "geometry": fp,
            }
        )
    return gpd.GeoDataFrame(rows, columns=TRUTH_COLUMNS, geometry="geometry", crs=crs)
