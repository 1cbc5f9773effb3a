"""Does a tower's window score survive when its points take the attributes of its surroundings?

A model can score 1.0 on generated zones by learning the colour, NIR or intensity contrast
that the generator paints on towers; on a real flight a tower is coloured by the
orthophoto pixel under it and reflects like anything else. :func:`swap_scores` measures
that directly: the classifier's probability of a window centred on a tower, with the
tower's points as they are, then with the attributes (intensity, returns, RGB, NIR) of
random points of the window's vegetation, of its ground, and of all its other points.
A model that recognises shapes keeps its score; one that keyed on the signature collapses.

:func:`tower_windows` builds such windows from a generated zone's blocks without the
pipeline: heights above ground from the blocks' own ground points (class 2), model input
= neither ground nor noise, as the preprocessing defines it.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from towerpipe import classes

#: The point dimensions a swap replaces (everything a feature set may read besides x, y, z).
SWAPPED = ("intensity", "return_number", "number_of_returns", "red", "green", "blue", "nir")
#: Where the replacing attributes come from: ASPRS classes (``None``: every non-tower point).
SOURCES: dict[str, tuple[int, ...] | None] = {
    "vegetation": classes.VEGETATION,
    "ground": (classes.GROUND,),
    "surroundings": None,
}


def tower_windows(
    block_paths: Sequence[str | os.PathLike[str]], truth, *, window: float = 40.0
) -> list[dict[str, Any]]:
    """One window per true tower: its points' arrays (with ``hag``), the tower mask and metadata.

    Parameters
    ----------
    block_paths
        The zone's LAS/LAZ blocks (labelled: class 15 = tower, 2 = ground).
    truth
        The zone's tower truth (``towers_truth.gpkg``): ``x``, ``y``, ``tower_id``, ``block``.
    window
        Window side (m), centred on the tower's base.
    """
    import laspy

    from towerpipe.io.las import laz_backend

    out = []
    for path in block_paths:
        las = laspy.read(path, laz_backend=laz_backend())
        dims = set(las.point_format.dimension_names)
        a = {
            "x": np.asarray(las.x),
            "y": np.asarray(las.y),
            "z": np.asarray(las.z),
            "classification": np.asarray(las.classification),
        }
        for d in SWAPPED:
            a[d] = np.asarray(las[d]) if d in dims else np.zeros(len(a["x"]), np.uint16)
        ground = a["classification"] == classes.GROUND
        tree = cKDTree(np.c_[a["x"][ground], a["y"][ground]])
        _, k = tree.query(np.c_[a["x"], a["y"]], k=6)
        a["hag"] = (a["z"] - a["z"][ground][k].mean(axis=1)).astype(np.float32)
        a["model_input"] = ~ground & ~np.isin(a["classification"], classes.NOISE) & (a["hag"] > -2) & (a["hag"] < 100)
        has_rgb = "red" in dims and a["red"].max() > 0
        meta = {
            "color_bits": 16,
            "valid_attributes": ["intensity", "returns"]
            + (["rgb"] if has_rgb else [])
            + (["nir"] if "nir" in dims and a["nir"].max() > 0 else []),
        }
        name = Path(path).stem
        for _, t in truth[truth["block"] == name].iterrows():
            c = np.array([float(t["x"]), float(t["y"])])
            sel = np.flatnonzero((np.abs(a["x"] - c[0]) <= window / 2) & (np.abs(a["y"] - c[1]) <= window / 2))
            win = {k: v[sel] for k, v in a.items()}
            tower = win["classification"] == classes.TOWER
            if tower.sum() < 20:
                continue
            out.append(
                {
                    "tower_id": int(t["tower_id"]),
                    "design": str(t["design"]),
                    "center": c,
                    "arrays": win,
                    "tower": tower,
                    "meta": meta,
                }
            )
    return out


def swap_scores(
    bundle, win: Mapping[str, Any], *, seed: int = 0, sources: Mapping[str, tuple[int, ...] | None] = SOURCES
) -> dict[str, float]:
    """Classifier probability of one tower window as it is and with swapped attributes.

    Parameters
    ----------
    bundle
        A model bundle (:class:`towerpipe.model.bundle.ModelBundle`).
    win
        One item of :func:`tower_windows`.
    seed
        The sampler's and the swap's seed (the same sample in every variant).
    sources
        Name -> classes whose points lend their attributes (``None``: all non-tower points).

    Returns
    -------
    dict
        ``own`` and one probability per source (absent where the window has no such points).
    """
    from towerpipe.model import features
    from towerpipe.model.sampling import constrained_sample

    a, tower = win["arrays"], win["tower"]
    mi = np.flatnonzero(a["model_input"])
    s = constrained_sample(a["hag"][mi], n=int(bundle.n_points), rng=np.random.default_rng(seed))
    variants = {"own": a}
    rng = np.random.default_rng(seed + 1)
    others = np.flatnonzero(~tower)
    for name, codes in sources.items():
        pool = others if codes is None else others[np.isin(a["classification"][others], codes)]
        if not len(pool):
            continue
        b = dict(a)
        take = pool[rng.integers(len(pool), size=int(tower.sum()))]
        for d in SWAPPED:
            b[d] = a[d].copy()
            b[d][tower] = a[d][take]
        variants[name] = b
    out = {}
    for name, arr in variants.items():
        meta = features.tile_feature_meta(arr, win["meta"])
        f = features.window_features(arr, mi, tuple(win["center"]), bundle.feature_set, meta, s)
        out[name] = float(np.asarray(bundle.classify(f[None]), dtype=np.float32).reshape(-1)[0])
    return out
