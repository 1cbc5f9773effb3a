"""Overhead wires among a tile's points: those the delivery classifies as wire, or the detector finds.

A conductor is as high as the tower it hangs from: the candidate windows leave it out of the
height peaks (:mod:`towerpipe.inference.candidates`), and the inference never paints it
(:func:`towerpipe.inference.infer.predict_tile`). A delivery that classifies no point as wire
(a flight delivered without a wire class) has its wires found by
:func:`towerpipe.towers.wires.wire_points`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from towerpipe import classes

__all__ = ["classified_wire", "overhead_wires", "wire_source"]


def classified_wire(arrays: Mapping[str, np.ndarray], idx: np.ndarray) -> np.ndarray:
    """Bool mask over ``idx``: the points the input classifies as wire
    (:data:`towerpipe.classes.WIRE`); none when the tile has no classification."""

    if "classification" not in arrays:
        return np.zeros(len(idx), bool)
    return np.isin(np.asarray(arrays["classification"])[idx], classes.WIRE)


def wire_source(arrays: Mapping[str, np.ndarray], idx: np.ndarray) -> str:
    """Where a tile's wires come from: ``"classified"`` when the delivery classifies any of the points
    ``idx`` as wire (:data:`towerpipe.classes.WIRE`), else ``"detected"`` (the wire detector's,
    :func:`overhead_wires`)."""
    return "classified" if classified_wire(arrays, idx).any() else "detected"


def overhead_wires(arrays: Mapping[str, np.ndarray], idx: np.ndarray, min_height: float) -> np.ndarray:
    """Bool mask over ``idx``: the points at least ``min_height`` high that look like overhead
    wire (:func:`towerpipe.towers.wires.wire_points`, or classified as wire:
    :data:`towerpipe.classes.WIRE`). A conductor is as high as the tower it hangs
    from, and one passing over a lower tower hides that tower's height peak."""
    from towerpipe.towers.wires import wire_points

    out = np.zeros(len(idx), bool)
    tall = np.flatnonzero(np.asarray(arrays["hag"])[idx] >= min_height)
    if len(tall):
        sel = idx[tall]
        out[tall] = wire_points(arrays["x"][sel], arrays["y"][sel], arrays["z"][sel])[0]
    # the detector misses conductors where they reach the crossarm
    return out | classified_wire(arrays, idx)
