"""A delivery without a wire class (synth key ``wire_class: false``): the same zone, its wires class 1."""

from __future__ import annotations

import laspy
import numpy as np

from towerpipe import classes
from towerpipe.synth import generate_zone


def test_a_zone_delivered_without_a_wire_class_differs_only_in_the_wires_class(tmp_path):
    kw = dict(seed=6, blocks=1, size=300, density=3, preset="catalonia", lines_per_km2=2.0)
    plain = generate_zone(tmp_path / "plain", **kw)
    bare = generate_zone(tmp_path / "bare", **kw, wire_class=False)
    (a,) = (laspy.read(p) for p in sorted((tmp_path / "plain").glob("*.la[sz]")))
    (b,) = (laspy.read(p) for p in sorted((tmp_path / "bare").glob("*.la[sz]")))
    ca, cb = np.asarray(a.classification), np.asarray(b.classification)
    wire = np.isin(ca, classes.WIRE)
    assert wire.sum() > 100  # the zone has a line
    assert not np.isin(cb, classes.WIRE).any()
    assert (cb[wire] == classes.OTHER).all() and (cb[~wire] == ca[~wire]).all()
    assert np.array_equal(np.asarray(a.x), np.asarray(b.x)) and np.array_equal(np.asarray(a.z), np.asarray(b.z))
    assert bare.towers["n_points"].tolist() == plain.towers["n_points"].tolist()


def test_a_real_background_zone_delivered_without_a_wire_class(tmp_path):
    """The benchmark's ``no_wire_class`` variant (and ``wire_class: false``): the same real-background
    zone, its conductors class 1."""
    from conftest import real_tile_zone

    kw = real_tile_zone(3, "uav", (8, 15), "ign_rgbnir_small.laz")
    zones = {
        name: generate_zone(tmp_path / name, **kw, **extra)
        for name, extra in (("intact", {}), ("variant", {"variant": "no_wire_class"}), ("key", {"wire_class": False}))
    }
    (a,) = (laspy.read(p) for p in sorted((tmp_path / "intact").glob("*.la[sz]")))
    ca = np.asarray(a.classification)
    wire = np.isin(ca, classes.WIRE)
    assert wire.sum() > 5  # the small tile holds a few spans
    for name in ("variant", "key"):
        (b,) = (laspy.read(p) for p in sorted((tmp_path / name).glob("*.la[sz]")))
        cb = np.asarray(b.classification)
        assert (
            not np.isin(cb, classes.WIRE).any() and (cb[wire] == classes.OTHER).all() and (cb[~wire] == ca[~wire]).all()
        )
        assert np.array_equal(np.asarray(a.z), np.asarray(b.z))
        assert zones[name].towers["n_points"].tolist() == zones["intact"].towers["n_points"].tolist()
