"""Lines strung otherwise than in full (towerpipe.synth.wires.strung): one circuit on one side of
a double-circuit line, no earth wire."""

from __future__ import annotations

import geopandas as gpd
import laspy
import numpy as np
import pytest

from towerpipe.synth import generate_zone
from towerpipe.synth.towers import DESIGNS, HEIGHTS, place_tower
from towerpipe.synth.wires import CIRCUIT_CONDUCTORS, strung


def _flat(x, y):
    return np.zeros(len(x))


def _tower(design, rot):
    lo, hi = HEIGHTS[design]
    return place_tower(1, design, 100.0, 200.0, rot, (lo + hi) / 2, _flat, np.random.default_rng(1))


def _across(t):
    """Each attachment's signed distance across the line (the tower's local x) and whether it is at the top."""
    a = t.attach
    across = np.cos(t.rot) * (a[:, 0] - t.x) + np.sin(t.rot) * (a[:, 1] - t.y)
    return across, a[:, 2] - t.base_z >= t.height - 0.05


def _double(across, top):
    """Whether the attachments hold a circuit on each side (three conductors or more a side)."""
    return min((~top & (across < -0.5)).sum(), (~top & (across > 0.5)).sum()) >= CIRCUIT_CONDUCTORS


@pytest.mark.parametrize("rot", [0.3, 2.0, -2.5])
@pytest.mark.parametrize("design", DESIGNS)
def test_one_side_keeps_one_circuit_and_the_earth_wire(design, rot):
    t = _tower(design, rot)
    across, top = _across(t)
    double = _double(across, top)
    assert strung(t).all()
    for side in (-1, 1):
        keep = strung(t, side)
        if not double:  # a single circuit hangs on both sides: nothing to leave out
            assert keep.all()
            continue
        assert keep[top].all()  # the earth wire stays
        kept = across[keep & ~top]
        assert len(kept) == CIRCUIT_CONDUCTORS and (np.sign(kept) == side).all()
    assert not strung(t, 0, earth_wire=False)[top].any() and strung(t, 0, earth_wire=False)[~top].all()


def test_double_circuit_designs_are_the_ones_with_three_conductors_a_side():
    double = {d for d in DESIGNS if _double(*_across(_tower(d, 0.0)))}
    assert double == {"double_circuit", "monopole", "donau", "einebenen", "tonne"}


def test_a_zone_strung_on_one_side_without_earth_wire(tmp_path):
    """A double-circuit line strung on one side, without an earth wire: the wire points of its span
    lie on one side of the line between its towers (one line crosses the zone, so no other line's
    wires cross the span). The towers themselves are those of the zone strung in full."""
    kw = dict(
        seed=6,
        blocks=2,
        size=400,
        density=3,
        preset="catalonia",
        lines_per_km2=0.0,
        parallel_line_share=0.0,
        designs=("double_circuit",),
        design_weights=(1.0,),
    )
    plain = generate_zone(tmp_path / "plain", **kw)
    t = generate_zone(tmp_path / "oneside", **kw, one_side_share=1.0, no_earth_wire_share=1.0)
    assert plain.meta["stringing"] == {} and t.meta["stringing"] == {"0": "one side, no earth wire"}
    assert t.towers["n_points"].tolist() == plain.towers["n_points"].tolist()
    assert min(_span_sides(plain)) > 20  # strung in full: conductors on both sides
    assert min(_span_sides(t)) == 0 and max(_span_sides(t)) > 20


def _span_sides(zone):
    """Wire points on the left and on the right of the zone's one span (its middle 80 %)."""
    ((a, b),) = np.asarray(zone.spans)
    truth = gpd.read_file(zone.out_dir / "towers_truth.gpkg", layer="towers").set_index("tower_id")
    pts = [laspy.read(blk["path"]) for blk in zone.blocks]
    wire = np.concatenate([np.asarray(p.classification) == 14 for p in pts])
    wx = np.concatenate([np.asarray(p.x) for p in pts])[wire]
    wy = np.concatenate([np.asarray(p.y) for p in pts])[wire]
    ax, ay, bx, by = truth.loc[a, "x"], truth.loc[a, "y"], truth.loc[b, "x"], truth.loc[b, "y"]
    d = np.array([bx - ax, by - ay])
    length = np.hypot(*d)
    along = ((wx - ax) * d[0] + (wy - ay) * d[1]) / length**2
    off = ((wx - ax) * d[1] - (wy - ay) * d[0]) / length  # signed, across the span
    near = (along > 0.1) & (along < 0.9) & (np.abs(off) < 14.0)
    return int((off[near] < -0.5).sum()), int((off[near] > 0.5).sum())
