"""Tests of towerpipe.towers.lines: towers linked into lines by the conductors between them."""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pytest
import shapely

from towerpipe.towers.lines import LINE_FIELDS, SPAN_FIELDS, build_lines

X0, Y0 = 400_000.0, 4_600_000.0
CRS = "EPSG:25831"


def conductors(a, b, offsets=(-7.0, 0.0, 7.0), step=1.0, rng=None, hag=15.0, clearance=np.nan):
    """Conductor points between towers a and b (plan), one wire per crossarm offset."""
    rng = rng or np.random.default_rng(0)
    a, b = np.asarray(a, float), np.asarray(b, float)
    v = b - a
    length = np.hypot(*v)
    u = v / length
    n = np.array([-u[1], u[0]])
    t = np.arange(0.0, length, step)
    pts = np.concatenate([a + t[:, None] * u + o * n for o in offsets])
    pts += rng.normal(0, 0.05, pts.shape)
    az = np.degrees(np.arctan2(u[0], u[1])) % 180.0 + rng.normal(0, 1.0, len(pts))
    return {
        "x": pts[:, 0],
        "y": pts[:, 1],
        "hag": np.full(len(pts), hag),
        "direction_deg": az % 180.0,
        "clearance_m": np.full(len(pts), clearance),
    }


def join(*parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def towers_at(points, ids=None):
    pts = np.asarray(points, float)
    ids = ids if ids is not None else [int(round(x)) * 10**8 + int(round(y)) % 10**8 for x, y in pts]
    return gpd.GeoDataFrame(
        {"tower_id": np.asarray(ids, np.int64), "centroid_x": pts[:, 0], "centroid_y": pts[:, 1]},
        geometry=[shapely.Point(x, y).buffer(4.0) for x, y in pts],
        crs=CRS,
    )


def line_order(towers, lid):
    on = towers[towers["line_id"] == lid].sort_values("line_seq")
    return on["tower_id"].tolist()


def test_an_angle_line_in_order_with_bearings_and_spans():
    # five towers; the line turns by 30 degrees at the third
    p = [np.array([X0, Y0])]
    for az in (45.0, 45.0, 75.0, 75.0):
        r = np.radians(az)
        p.append(p[-1] + 300.0 * np.array([np.sin(r), np.cos(r)]))
    # the conductors leave the zone on both sides of the end towers
    ext0 = p[0] - 200 * (p[1] - p[0]) / 300
    ext4 = p[4] + 200 * (p[4] - p[3]) / 300
    cond = join(
        conductors(ext0, p[0]),
        *[conductors(p[i], p[i + 1], clearance=8.0 + i) for i in range(4)],
        conductors(p[4], ext4),
    )
    towers = towers_at(p)
    shuffled = towers.sample(frac=1.0, random_state=3).reset_index(drop=True)
    out, lines, spans = build_lines(shuffled, cond)
    assert len(lines) == 1 and list(lines.columns) == list(LINE_FIELDS) + ["geometry"]
    ids = towers["tower_id"].tolist()
    order = line_order(out, lines.iloc[0]["line_id"])
    assert order == ids or order == ids[::-1]
    assert lines.iloc[0]["line_id"] == min(ids) and lines.iloc[0]["tower_count"] == 5
    assert lines.iloc[0]["length_m"] == pytest.approx(1200.0, abs=0.1)
    assert list(spans.columns) == list(SPAN_FIELDS) + ["geometry"] and len(spans) == 4
    assert spans["mutual"].all() and (spans["conductor_coverage"] == 1.0).all()
    np.testing.assert_allclose(spans["length_m"], 300.0, atol=0.01)
    first = out.set_index("tower_id").loc[order[0]]
    assert first["line_seq"] == 1 and first["line_chainage_m"] == 0 and np.isnan(first["deflection_deg"])
    mid = out.set_index("tower_id").loc[order[2]]
    assert mid["deflection_deg"] == pytest.approx(30.0, abs=0.1)
    # at the angle tower the line runs along the bisector
    assert mid["bearing_deg"] % 180 == pytest.approx(60.0, abs=0.2)
    assert mid["line_chainage_m"] == pytest.approx(600.0, abs=0.1)
    assert spans["bearing_deg"].iloc[0] % 180 == pytest.approx(45.0, abs=0.1)
    assert spans["clearance_m"].min() == pytest.approx(8.0)
    # the span geometry joins its towers, the line goes through all of them in order
    line = lines.geometry.iloc[0]
    pos = out.set_index("tower_id").loc[order, ["centroid_x", "centroid_y"]].to_numpy()
    np.testing.assert_allclose(np.asarray(line.coords), pos)


def test_a_parallel_line_and_a_line_passing_by_are_not_taken():
    """Line A (south-north) with a twin 28 m east whose towers are staggered; line B (west-east)
    passes 14 m from A's middle tower without hanging on it."""
    a = [np.array([X0, Y0 + 300.0 * k]) for k in range(4)]
    twin = [np.array([X0 + 28.0, Y0 + 60.0 + 280.0 * k]) for k in range(4)]
    b = [np.array([X0 - 250.0, Y0 + 314.0]), np.array([X0 + 250.0, Y0 + 314.0])]
    cond = join(
        *[conductors(a[i], a[i + 1]) for i in range(3)],
        *[conductors(twin[i], twin[i + 1]) for i in range(3)],
        conductors(b[0], b[1]),
    )
    towers = towers_at(a + twin + b)
    out, lines, spans = build_lines(towers, cond)
    ids = towers["tower_id"].tolist()
    assert len(lines) == 3
    lines_of = {lid: line_order(out, lid) for lid in lines["line_id"]}
    assert sorted(map(sorted, lines_of.values())) == sorted([sorted(ids[:4]), sorted(ids[4:8]), sorted(ids[8:])])
    for order in lines_of.values():
        group = next(g for g in (ids[:4], ids[4:8], ids[8:]) if set(g) == set(order))
        assert order == group or order == group[::-1]
    assert len(spans) == 3 + 3 + 1


def test_a_line_across_the_data_edge_and_a_tower_without_spans():
    """Bins outside the data are not judged; a lone tower on a line gets the bearing of its conductors."""
    a, b = np.array([X0, Y0]), np.array([X0 + 400.0, Y0])
    # the data stops at x0 + 150: no conductor points beyond
    cond = conductors(a, b)
    keep = cond["x"] < X0 + 150
    cond = {k: v[keep] for k, v in cond.items()}
    lone = np.array([X0 + 100.0, Y0 + 500.0])
    cond = join(cond, conductors(lone - [0, 200], lone), conductors(lone, lone + [0, 200]))
    towers = towers_at([a, b, lone])
    extent = shapely.box(X0 - 50, Y0 - 50, X0 + 150, Y0 + 800)
    out, lines, spans = build_lines(towers, cond, extent=extent)
    assert len(spans) == 1 and spans.iloc[0]["conductor_coverage"] == 1.0
    # judged everywhere, the missing conductors refuse the span
    out2, lines2, spans2 = build_lines(towers, cond)
    assert len(spans2) == 0 and len(lines2) == 0
    assert out2["line_id"].isna().all() and out2["line_seq"].isna().all()
    row = out2.set_index("tower_id").loc[towers["tower_id"].iloc[2]]
    assert min(row["bearing_deg"], 180.0 - row["bearing_deg"]) == pytest.approx(0.0, abs=1.0)  # north-south


def test_no_towers_and_no_conductors():
    empty = towers_at(np.zeros((0, 2)), ids=[])
    out, lines, spans = build_lines(empty, {})
    assert len(out) == len(lines) == len(spans) == 0
    out, lines, spans = build_lines(towers_at([[X0, Y0], [X0 + 300, Y0]]), {})
    assert len(lines) == 0 and out["line_id"].isna().all() and out["bearing_deg"].isna().all()
