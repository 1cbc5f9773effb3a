"""Doubled lines (towerpipe.synth.wires.make_power_lines): a twin line ``parallel_gap`` m aside,
its towers beside the first line's with ``twin_beside_share``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from towerpipe.synth.params import preset
from towerpipe.synth.wires import make_power_lines

BOUNDS = (0.0, 0.0, 1500.0, 1500.0)


def _flat(x, y):
    return np.zeros(np.shape(x))


def _lines(**kw):
    p = preset("catalonia", lines_per_km2=0.0, min_lines=1, deflections=(0, 0), **kw)
    return make_power_lines(3, BOUNDS, p, _flat).towers


def _nearest_across_lines(towers):
    """Each twin-line tower's distance (m) to the nearest tower of the first line."""
    first = np.array([(t.x, t.y) for t in towers if t.line_id == 0])
    twin = np.array([(t.x, t.y) for t in towers if t.line_id == 1])
    assert len(first) >= 3 and len(twin) >= 3
    return cKDTree(first).query(twin)[0]


@pytest.mark.parametrize("gap", [(10.0, 12.0), (16.0, 18.0)])
def test_twin_towers_stand_beside_the_first_lines(gap):
    d = _nearest_across_lines(_lines(parallel_line_share=1.0, parallel_gap=gap, twin_beside_share=1.0))
    # beside: the gap across and at most 2 m along
    assert d.min() >= gap[0] - 1e-6 and d.max() <= np.hypot(gap[1], 2.0) + 1e-6


def test_twin_towers_otherwise_placed_on_their_own():
    d = _nearest_across_lines(_lines(parallel_line_share=1.0, parallel_gap=(10.0, 12.0)))
    assert d.max() > 20.0  # stations of its own: towers far from the first line's


def test_the_beside_share_moves_the_twins_only():
    """The first line and the twin's route and design are drawn as without the share: only the
    twin's stations move (a zone without it keeps its layout, docs/model.md "Towers side by side")."""
    p = dict(parallel_line_share=1.0, parallel_gap=(10.0, 12.0))
    alone = _lines(**p)
    beside = _lines(**p, twin_beside_share=1.0)
    first = [[(t.x, t.y, t.height, t.design) for t in towers if t.line_id == 0] for towers in (alone, beside)]
    assert first[0] == first[1] and len(first[0]) >= 3
    assert {t.design for t in alone if t.line_id == 1} == {t.design for t in beside if t.line_id == 1}
    assert [(t.x, t.y) for t in alone if t.line_id == 1] != [(t.x, t.y) for t in beside if t.line_id == 1]
