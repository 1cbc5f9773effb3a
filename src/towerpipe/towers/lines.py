"""Power lines: towers linked by the conductors between them, and the spans they form.

Built for a whole zone at once (:func:`build_lines`), when every tower and every
conductor point is known: a line crosses many blocks, and its spans cross block edges.
The conductor points are those :func:`towerpipe.towers.wires.conductor_points` finds in each
block (wire-like points with air above and below, locally straight and level).

1. **Conductor rays.** Around each tower, the conductor points whose wire, extended
   along its local direction, passes within ``max_offset`` (12 m, the crossarm) of the
   tower are grouped by the direction they leave the tower in (gaps over ``ray_gap``
   degrees split groups). A group of at least ``min_ray_points`` points is a *ray*: its
   bearing is the mean direction of its wires (precise to a fraction of a degree: every
   conductor of a span runs parallel to it, whatever its offset on the crossarm).
2. **Spans.** Along each ray, the nearest tower lying within ``lateral`` of it (10 m +
   2 % of the distance: a parallel line 24 m aside is not taken) between ``min_span``
   and ``max_span`` is the next tower, if the conductors really run between them: the
   conductor points in the 15 m corridor of the span, parallel to it, must fill at least
   ``min_coverage`` of its 10 m bins (bins outside the data, the assembled blocks, are not
   counted). A span found from both towers is ``mutual``.
3. **Lines.** Spans chain into lines through towers with two spans. At a tower with
   more (a branch), the two spans closest to a straight line carry the line through; the
   others start or end a branch line there. A line runs from its end tower with the
   smaller id to the other; its id is the smallest ``tower_id`` of the towers it holds,
   so it stays as long as that tower does.

:func:`towerpipe.jobs.lines.lines_across_zones` (``towerpipe lines results/z1 results/z2 -o
lines.gpkg``) does the same for several published zones at once, so a line crossing a zone
border is one line.

Each tower gets ``line_id``, ``line_seq`` (1, 2, … along the line), ``line_chainage_m``,
``bearing_deg`` (the line at the tower, toward increasing ``line_seq``; a bisector at an
angle tower; the axis of its rays for a tower on no line) and ``deflection_deg``. Each
span gets its length, bearing, conductor points, the lowest conductor's height above
ground and the clearance down to the vegetation below the conductors.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from scipy.spatial import cKDTree

from towerpipe.io.fields import Field, conform, empty_frame
from towerpipe.towers.wires import WIRE_MIN_HAG_M

__all__ = ["LINE_FIELDS", "SPAN_FIELDS", "LINE_TOWER_COLUMNS", "LineParams", "build_lines", "conductor_rays"]

#: Fields of the ``lines`` layer (LineString through the towers, in line order).
LINE_FIELDS: dict[str, Field] = {
    "line_id": Field("int64", "Line id", "Smallest tower_id of the towers of the line"),
    "tower_count": Field("int64", "Towers", "Towers on the line"),
    "span_count": Field("int64", "Spans", "Spans of the line"),
    "length_m": Field("float64", "Length (m)", "Length through its towers, in plan (m)", 2),
    "first_tower": Field("int64", "First tower", "tower_id of the tower with line_seq 1"),
    "last_tower": Field("int64", "Last tower", "tower_id of the line's last tower"),
}

#: Fields of the ``spans`` layer (LineString from tower to tower).
SPAN_FIELDS: dict[str, Field] = {
    "line_id": Field("int64", "Line id", "Line of the span"),
    "span_seq": Field("int64", "Span on the line", "1 for the span from line_seq 1 to 2, …"),
    "from_tower": Field("int64", "From tower", "tower_id at the start (lower line_seq)"),
    "to_tower": Field("int64", "To tower", "tower_id at the end"),
    "length_m": Field("float64", "Length (m)", "Distance between the tower centroids, in plan (m)", 2),
    "bearing_deg": Field(
        "float64", "Bearing (°)", "Azimuth from from_tower to to_tower, degrees clockwise from grid north", 1
    ),
    "conductor_points": Field("int64", "Conductor points", "Conductor points in the span's corridor, running along it"),
    "conductor_coverage": Field(
        "float64",
        "Conductor coverage (0-1)",
        "Share of the span's 10 m bins (inside the data) holding a conductor point",
        3,
    ),
    "lowest_conductor_m": Field(
        "float64",
        "Lowest conductor (m)",
        "Lowest conductor point above ground in the span, away from the towers (m). Conductor "
        f"points are looked for from {WIRE_MIN_HAG_M:g} m above ground: a value near {WIRE_MIN_HAG_M:g} m "
        "is the floor of the search, the conductor may hang lower",
        2,
    ),
    "clearance_m": Field(
        "float64",
        "Clearance to vegetation (m)",
        "Smallest vertical distance from a conductor point of the span down to the vegetation "
        "(classes 3-5) within 2 m in plan below it, over the conductor points found (see "
        "lowest_conductor_m: a conductor lower than the search's floor is not among them); NULL "
        "when no vegetation lies below (m)",
        2,
    ),
    "mutual": Field(
        "bool",
        "Seen from both towers",
        "Conductors were found leaving both towers toward each other (else from one of them only)",
    ),
}

#: Tower columns :func:`build_lines` fills.
LINE_TOWER_COLUMNS = ("line_id", "line_seq", "line_chainage_m", "bearing_deg", "deflection_deg")


@dataclass(frozen=True)
class LineParams:
    """Parameters of :func:`build_lines` (metres and degrees)."""

    r_min: float = 20.0  # conductor points closer to a tower are its body and crossarms
    max_offset: float = 12.0  # a wire aims at a tower when its line passes this close
    ray_gap: float = 6.0  # directions further apart than this start a new ray
    min_ray_points: int = 10  # points a ray needs
    min_span: float = 30.0
    max_span: float = 700.0
    lateral: float = 5.0  # + lateral_share * distance: how far off a ray the next tower may be
    lateral_share: float = 0.015
    back_angle: float = 20.0  # a ray of the far tower within this of the way back must find the near one
    attached_offset: float = 4.0  # median offset of a ray's wires from a tower they hang on
    corridor: float = 15.0  # half-width of a span's corridor
    parallel: float = 10.0  # conductor direction vs span bearing
    bin: float = 10.0
    min_coverage: float = 0.5
    min_bins: int = 3  # bins in the data a span needs to be judged


def _unit(az_deg: np.ndarray | float) -> np.ndarray:
    a = np.radians(az_deg)
    return np.stack([np.sin(a), np.cos(a)], axis=-1)


def _azimuth(dx: np.ndarray | float, dy: np.ndarray | float) -> np.ndarray:
    return np.degrees(np.arctan2(dx, dy)) % 360.0


def _angle_diff(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """Smallest absolute difference of two azimuths (0-180)."""
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


def conductor_rays(
    tree: cKDTree, xy: np.ndarray, direction_deg: np.ndarray, cx: float, cy: float, p: LineParams = LineParams()
) -> list[dict[str, float]]:
    """The conductor rays leaving a tower at ``(cx, cy)``.

    Parameters
    ----------
    tree, xy, direction_deg
        KD-tree of the conductor points' ``xy`` and their wire axes (azimuth 0-180).
    cx, cy
        The tower.

    Returns
    -------
    list of dict
        ``bearing_deg`` (0-360, away from the tower), ``n_points``, ``reach_m`` (farthest
        point), ``median_offset_m`` (median signed offset of its wires from the tower: near 0
        for conductors hanging on both sides of it, large for a line passing by), sorted
        by bearing.
    """
    idx = np.asarray(tree.query_ball_point([cx, cy], p.max_span), dtype=np.int64)
    if len(idx) < p.min_ray_points:
        return []
    d = xy[idx] - (cx, cy)
    r = np.hypot(d[:, 0], d[:, 1])
    u = _unit(direction_deg[idx])
    offset = np.abs(d[:, 0] * u[:, 1] - d[:, 1] * u[:, 0])
    keep = (r >= p.r_min) & (offset <= p.max_offset)
    if keep.sum() < p.min_ray_points:
        return []
    d, r, u = d[keep], r[keep], u[keep]
    u = np.where(((d * u).sum(axis=1) < 0)[:, None], -u, u)  # the wire's direction away from the tower
    out_az = _azimuth(u[:, 0], u[:, 1])
    order = np.argsort(out_az)
    a = out_az[order]
    gaps = np.diff(np.r_[a, a[0] + 360.0])
    cuts = np.flatnonzero(gaps > p.ray_gap)
    if len(cuts) == 0:  # one group all round: no direction stands out
        return []
    # groups between the cuts (gap after an element > ray_gap); the one across 0/360 joined
    start = (cuts[-1] + 1) % len(a)
    ring = np.roll(order, -start)
    labels = np.r_[0, np.cumsum(np.roll(gaps, -start)[:-1] > p.ray_gap)]
    side = d[:, 0] * u[:, 1] - d[:, 1] * u[:, 0]  # signed offset of each wire from the tower
    rays = []
    for k in np.unique(labels):
        members = ring[labels == k]
        if len(members) < p.min_ray_points:
            continue
        v = u[members].mean(axis=0)
        rays.append(
            {
                "bearing_deg": float(_azimuth(v[0], v[1])),
                "n_points": int(len(members)),
                "reach_m": float(r[members].max()),
                "median_offset_m": float(np.median(side[members])),
            }
        )
    return sorted(rays, key=lambda ray: ray["bearing_deg"])


def _corridor(
    tree: cKDTree,
    xy: np.ndarray,
    cond: Mapping[str, np.ndarray],
    a: np.ndarray,
    b: np.ndarray,
    p: LineParams,
    extent: Any,
) -> dict[str, Any]:
    """Conductor evidence of the span ``a`` → ``b``."""
    v = b - a
    length = float(np.hypot(*v))
    unit = v / length
    mid = (a + b) / 2.0
    idx = np.asarray(tree.query_ball_point(mid, length / 2.0 + p.corridor), dtype=np.int64)
    d = xy[idx] - a
    t = d @ unit
    lat = np.abs(d[:, 0] * unit[1] - d[:, 1] * unit[0])
    span_az = float(_azimuth(unit[0], unit[1]))
    axis_dev = np.minimum(
        _angle_diff(cond["direction_deg"][idx], span_az), _angle_diff(cond["direction_deg"][idx] + 180.0, span_az)
    )
    end = min(p.r_min, length / 4.0)  # the towers' own points near each end (less on a short span)
    inner = (t >= end) & (t <= length - end)
    sel = (t >= 0) & (t <= length) & (lat <= p.corridor) & (axis_dev <= p.parallel)
    nbins = max(int(np.ceil((length - 2 * end) / p.bin)), 0)
    if nbins:
        centres = a + unit * (end + p.bin * (np.arange(nbins) + 0.5))[:, None]
        in_data = np.ones(nbins, bool) if extent is None else shapely.contains_xy(extent, centres[:, 0], centres[:, 1])
        hit = np.zeros(nbins, bool)
        k = np.floor((t[sel & inner] - end) / p.bin).astype(np.int64)
        hit[np.clip(k, 0, nbins - 1)] = True
        judged = int(in_data.sum())
        coverage = float((hit & in_data).sum() / judged) if judged else float("nan")
    else:
        judged, coverage = 0, float("nan")
    mid_sel = idx[sel & inner]
    hag = cond["hag"][mid_sel]
    clear = cond["clearance_m"][mid_sel]
    clear = clear[np.isfinite(clear)]
    return {
        "length_m": length,
        "bearing_deg": span_az,
        "conductor_points": int(sel.sum()),
        "conductor_coverage": coverage,
        "judged_bins": judged,
        "lowest_conductor_m": float(hag.min()) if len(hag) else float("nan"),
        "clearance_m": float(clear.min()) if len(clear) else float("nan"),
    }


def _next_tower(i: int, ray: Mapping[str, float], txy: np.ndarray, p: LineParams) -> int | None:
    """The nearest tower along a ray of tower ``i`` (within the lateral tolerance), or None."""
    unit = _unit(ray["bearing_deg"])
    d = txy - txy[i]
    s = d @ unit
    lat = np.abs(d[:, 0] * unit[1] - d[:, 1] * unit[0])
    cand = np.flatnonzero((s >= p.min_span) & (s <= p.max_span) & (lat <= p.lateral + p.lateral_share * s))
    return int(cand[np.argmin(s[cand])]) if len(cand) else None


def _spans(
    txy: np.ndarray,
    rays: list[list[dict[str, float]]],
    tree: cKDTree,
    xy: np.ndarray,
    cond: Mapping[str, np.ndarray],
    p: LineParams,
    extent: Any,
) -> dict[tuple[int, int], dict]:
    """Spans ``(i, j)`` (tower row indices, i < j) with their evidence.

    A span is proposed by a ray of a tower whose next tower is the other; proposed by
    one tower only, it is refused when the other has a ray toward the first (that ray
    found another tower, or none where the first stands).
    """
    proposed: dict[tuple[int, int], set[int]] = {}
    for i, tower_rays in enumerate(rays):
        for ray in tower_rays:
            j = _next_tower(i, ray, txy, p)
            if j is not None:
                proposed.setdefault((min(i, j), max(i, j)), set()).add(i)
    spans: dict[tuple[int, int], dict] = {}
    for key, by in sorted(proposed.items()):
        mutual = len(by) == 2
        if not mutual:
            near = next(iter(by))
            far = key[1] if near == key[0] else key[0]
            back = float(_azimuth(*(txy[near] - txy[far])))
            if any(_angle_diff(r["bearing_deg"], back) <= p.back_angle for r in rays[far]):
                continue
        ev = _corridor(tree, xy, cond, txy[key[0]], txy[key[1]], p, extent)
        if ev["judged_bins"] < p.min_bins or not ev["conductor_coverage"] >= p.min_coverage:
            continue
        spans[key] = dict(ev, mutual=mutual)
    return spans


def _through(node: int, edges: list[tuple[int, int]], txy: np.ndarray) -> tuple[int, int] | None:
    """The two edges (indices into ``edges``) that carry the line through ``node`` (straightest pair)."""
    if len(edges) < 2:
        return None
    az = [float(_azimuth(*(txy[other] - txy[node]))) for other, _ in edges]
    best, pair = None, None
    for a in range(len(edges)):
        for b in range(a + 1, len(edges)):
            straight = 180.0 - float(_angle_diff(az[a], az[b]))  # 0 = opposite directions
            key = (straight, min(edges[a][0], edges[b][0]))
            if best is None or key < best:
                best, pair = key, (edges[a][1], edges[b][1])
    return pair


def _paths(n: int, keys: list[tuple[int, int]], txy: np.ndarray, tids: np.ndarray) -> list[list[int]]:
    """Tower sequences of the lines, from the spans ``keys``."""
    incident: list[list[tuple[int, int]]] = [[] for _ in range(n)]  # (other tower, edge index)
    for e, (i, j) in enumerate(keys):
        incident[i].append((j, e))
        incident[j].append((i, e))
    through = [_through(v, incident[v], txy) for v in range(n)]

    def next_edge(node: int, edge: int) -> int | None:
        pair = through[node]
        if pair is None or edge not in pair:
            return None
        return pair[1] if pair[0] == edge else pair[0]

    used = np.zeros(len(keys), bool)
    paths = []
    # start at towers where a line ends (an edge that does not continue), smallest id first
    starts = sorted(((int(tids[v]), v, e) for v in range(n) for _, e in incident[v] if next_edge(v, e) is None))
    for _, v, e in starts + sorted((int(tids[keys[e][0]]), keys[e][0], e) for e in range(len(keys))):
        if used[e]:
            continue
        path, node, edge = [v], v, e
        while edge is not None and not used[edge]:
            used[edge] = True
            i, j = keys[edge]
            node = j if node == i else i
            path.append(node)
            edge = next_edge(node, edge)
        paths.append(path)
    # each line runs from the end with the smaller id (a ring from its smallest tower)
    out = []
    for path in paths:
        if path[0] == path[-1] and len(path) > 2:  # ring
            ring = path[:-1]
            k = int(np.argmin(tids[ring]))
            ring = ring[k:] + ring[:k]
            if tids[ring[-1]] < tids[ring[1]]:
                ring = [ring[0]] + ring[1:][::-1]
            out.append(ring + [ring[0]])
        else:
            out.append(path if tids[path[0]] <= tids[path[-1]] else path[::-1])
    return out


def build_lines(
    towers: gpd.GeoDataFrame,
    conductors: Mapping[str, np.ndarray],
    *,
    extent: Any = None,
    params: LineParams = LineParams(),
) -> tuple[gpd.GeoDataFrame, gpd.GeoDataFrame, gpd.GeoDataFrame]:
    """Link a zone's towers into lines.

    Parameters
    ----------
    towers
        The zone's towers (``tower_id``, ``centroid_x``, ``centroid_y``; any other columns
        are kept).
    conductors
        Conductor points of the zone: ``x, y, hag, direction_deg, clearance_m`` arrays
        (:func:`towerpipe.towers.wires.conductor_points`, all blocks together).
    extent
        Where there is data (a shapely geometry, e.g. the union of the blocks): span bins
        outside it are not judged. ``None``: everywhere.
    params
        :class:`LineParams`.

    Returns
    -------
    towers
        ``towers`` with :data:`LINE_TOWER_COLUMNS` filled.
    lines, spans
        GeoDataFrames of :data:`LINE_FIELDS` and :data:`SPAN_FIELDS` (LineStrings).
    """
    p = params
    crs = towers.crs
    out = towers.copy().reset_index(drop=True)
    n = len(out)
    for col in LINE_TOWER_COLUMNS:
        out[col] = pd.array([None] * n, dtype="Int64") if col in ("line_id", "line_seq") else np.nan
    if n == 0:
        return out, empty_frame(LINE_FIELDS, crs), empty_frame(SPAN_FIELDS, crs)
    tids = out["tower_id"].to_numpy(np.int64)
    txy = np.c_[out["centroid_x"].to_numpy(float), out["centroid_y"].to_numpy(float)]
    cond = {
        k: np.asarray(conductors.get(k, []), dtype=np.float64)
        for k in ("x", "y", "hag", "direction_deg", "clearance_m")
    }
    xy = np.c_[cond["x"], cond["y"]]
    tree = cKDTree(xy) if len(xy) else None
    rays = [conductor_rays(tree, xy, cond["direction_deg"], *txy[i], p) if tree is not None else [] for i in range(n)]
    spans = _spans(txy, rays, tree, xy, cond, p, extent) if tree is not None else {}
    keys = sorted(spans)
    paths = _paths(n, keys, txy, tids)

    # line ids: the smallest id of the towers a line holds (a junction tower is held by its through line)
    owner = np.full(n, -1)
    for k, path in enumerate(paths):
        for v in path[1:-1] if len(path) > 2 else []:
            owner[v] = k
    for k, path in enumerate(paths):
        for v in (path[0], path[-1]):
            if owner[v] < 0:
                owner[v] = k
    line_ids, used = [], set()
    for k, path in enumerate(paths):
        prefer = sorted(int(tids[v]) for v in set(path) if owner[v] == k) + sorted(int(tids[v]) for v in set(path))
        lid = next(t for t in prefer if t not in used)
        used.add(lid)
        line_ids.append(lid)

    line_rows, line_geoms, span_rows, span_geoms = [], [], [], []
    for k, path in enumerate(paths):
        pts = txy[path]
        seg = np.hypot(*np.diff(pts, axis=0).T)
        chain = np.r_[0.0, np.cumsum(seg)]
        for seq, v in enumerate(path):
            if owner[v] != k or not pd.isna(out.at[v, "line_seq"]):
                continue
            prev_ = pts[seq - 1] if seq > 0 else None
            next_ = pts[seq + 1] if seq + 1 < len(path) else None
            dirs = [
                w
                for w in (
                    (pts[seq] - prev_) if prev_ is not None else None,
                    (next_ - pts[seq]) if next_ is not None else None,
                )
                if w is not None
            ]
            units = [w / np.hypot(*w) for w in dirs]
            mean = np.sum(units, axis=0)
            out.at[v, "line_id"] = line_ids[k]
            out.at[v, "line_seq"] = seq + 1
            out.at[v, "line_chainage_m"] = float(chain[seq])
            out.at[v, "bearing_deg"] = float(_azimuth(*mean)) if np.hypot(*mean) > 1e-9 else float(_azimuth(*units[0]))
            out.at[v, "deflection_deg"] = (
                float(_angle_diff(_azimuth(*units[0]), _azimuth(*units[1]))) if len(units) == 2 else np.nan
            )
        line_rows.append(
            {
                "line_id": line_ids[k],
                "tower_count": len(set(path)),
                "span_count": len(path) - 1,
                "length_m": float(chain[-1]),
                "first_tower": int(tids[path[0]]),
                "last_tower": int(tids[path[-1]]),
            }
        )
        line_geoms.append(shapely.LineString(pts))
        for s, (a, b) in enumerate(zip(path[:-1], path[1:])):
            ev = spans[(min(a, b), max(a, b))]
            span_rows.append(
                {
                    "line_id": line_ids[k],
                    "span_seq": s + 1,
                    "from_tower": int(tids[a]),
                    "to_tower": int(tids[b]),
                    "length_m": ev["length_m"],
                    "bearing_deg": float(_azimuth(*(txy[b] - txy[a]))),
                    "conductor_points": ev["conductor_points"],
                    "conductor_coverage": ev["conductor_coverage"],
                    "lowest_conductor_m": ev["lowest_conductor_m"],
                    "clearance_m": ev["clearance_m"],
                    "mutual": bool(ev["mutual"]),
                }
            )
            span_geoms.append(shapely.LineString([txy[a], txy[b]]))
    # towers on no line: the axis of the conductors hanging on them (rays centred on the tower)
    for v in range(n):
        if pd.isna(out.at[v, "line_id"]) and rays[v]:
            hung = [r for r in rays[v] if abs(r["median_offset_m"]) <= p.attached_offset] or rays[v]
            doubled = np.radians(2.0 * np.array([r["bearing_deg"] for r in hung]))
            w = np.array([r["n_points"] for r in hung], float)
            axis = np.degrees(np.arctan2((w * np.sin(doubled)).sum(), (w * np.cos(doubled)).sum())) / 2.0
            out.at[v, "bearing_deg"] = float(axis % 180.0)
    lines = gpd.GeoDataFrame(line_rows, geometry=line_geoms, crs=crs) if line_rows else empty_frame(LINE_FIELDS, crs)
    span_df = gpd.GeoDataFrame(span_rows, geometry=span_geoms, crs=crs) if span_rows else empty_frame(SPAN_FIELDS, crs)
    lines = conform(lines.sort_values("line_id", kind="stable"), LINE_FIELDS, crs)
    span_df = conform(span_df.sort_values(["line_id", "span_seq"], kind="stable"), SPAN_FIELDS, crs)
    return out, lines, span_df
