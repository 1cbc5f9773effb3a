"""Sensor attributes: which a block carries, and whether each carries information.

A LAS point format can hold a dimension that the export filled with nothing: public ALS
derivatives often have intensity, return numbers, scan angle and GPS time all 0, a
colourised file can hold a NIR channel of zeros, and a re-export can leave colour
constant. A model fed such a column sees a constant where it learned a signal, so what
matters is not whether a dimension exists but whether it varies. While a block is split
(:func:`towerpipe.preprocess.split.split_block`) an :class:`AttributeStats` sees every chunk
and decides, per attribute of :data:`ATTRIBUTES`:

``intensity``
    valid with more than :data:`MIN_DISTINCT` distinct values;
``returns``
    valid when return numbers and numbers of returns are not all 0 and the pulses do not
    all have a single return (a constant carries no information);
``rgb``
    valid when the colour channels exist and hold more than :data:`MIN_DISTINCT` distinct
    values (not all 0, not constant);
``nir``
    valid when the NIR channel exists and holds more than :data:`MIN_DISTINCT` distinct values.

The result (:meth:`AttributeStats.result`) is recorded in the block cache and summary as
``attributes`` (``{name: {"present", "valid", "reason"}}``) plus
``degenerate_attributes``: the attributes whose dimensions exist but carry nothing, which
the QA page flags. Model choice (:mod:`towerpipe.model.choice`) uses only valid attributes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

#: The sensor attributes a model may use, in a fixed order.
ATTRIBUTES: tuple[str, ...] = ("intensity", "returns", "rgb", "nir")
#: An attribute with at most this many distinct values carries no information.
MIN_DISTINCT = 8
#: The point dimensions behind each attribute.
DIMENSIONS: dict[str, tuple[str, ...]] = {
    "intensity": ("intensity",),
    "returns": ("return_number", "number_of_returns"),
    "rgb": ("red", "green", "blue"),
    "nir": ("nir",),
}


def _distinct(values: np.ndarray) -> np.ndarray:
    """The distinct values of a chunk (a count per possible value for 8- and 16-bit unsigned
    dimensions, the LAS colours, intensities and return numbers: one pass, no sort)."""
    if values.dtype.kind == "u" and values.dtype.itemsize <= 2:
        return np.flatnonzero(np.bincount(values.ravel(), minlength=1))
    return np.unique(values)


class AttributeStats:
    """Accumulates, chunk by chunk, what decides each attribute's validity.

    Parameters
    ----------
    dimensions
        The point dimensions of the file (an attribute whose dimensions are missing is
        absent, not degenerate).
    """

    def __init__(self, dimensions: Iterable[str]):
        dims = set(dimensions)
        self.present = {a: all(d in dims for d in DIMENSIONS[a]) for a in ATTRIBUTES}
        self._distinct: dict[str, set[int]] = {d: set() for a in ATTRIBUTES if self.present[a] for d in DIMENSIONS[a]}
        self.points = 0

    def update(self, chunk: Mapping[str, np.ndarray]) -> None:
        """Add one chunk of points (arrays by dimension name)."""
        self.points += len(next(iter(chunk.values()))) if chunk else 0
        for dim, seen in self._distinct.items():
            if len(seen) > MIN_DISTINCT or dim not in chunk:
                continue  # decided already: enough distinct values seen
            seen.update(_distinct(np.asarray(chunk[dim])).tolist())

    def _distinct_count(self, attribute: str) -> int:
        return len(set().union(*(self._distinct[d] for d in DIMENSIONS[attribute])))

    def result(self) -> dict[str, dict[str, Any]]:
        """``{attribute: {"present": bool, "valid": bool, "reason": str}}``."""
        out: dict[str, dict[str, Any]] = {}
        for a in ATTRIBUTES:
            if not self.present[a]:
                out[a] = {"present": False, "valid": False, "reason": "not in the point format"}
                continue
            if a == "returns":
                rn, nr = self._distinct["return_number"], self._distinct["number_of_returns"]
                if rn <= {0} or nr <= {0}:
                    valid, reason = False, "return numbers all 0"
                elif len(rn) == 1 and len(nr) == 1:
                    valid, reason = False, f"every point is return {min(rn)} of {min(nr)}"
                else:
                    valid, reason = True, f"up to {max(nr)} returns per pulse"
            else:
                k = self._distinct_count(a)
                seen = set().union(*(self._distinct[d] for d in DIMENSIONS[a]))
                if seen <= {0}:
                    valid, reason = False, "all 0"
                elif k <= MIN_DISTINCT:
                    valid, reason = False, f"only {k} distinct value{'s' if k > 1 else ''}"
                else:
                    valid, reason = True, f"more than {MIN_DISTINCT} distinct values"
            out[a] = {"present": True, "valid": valid, "reason": reason}
        return out


def degenerate(attributes: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The attributes whose dimensions exist but carry no information."""
    return [a for a in ATTRIBUTES if a in attributes and attributes[a]["present"] and not attributes[a]["valid"]]


def valid_set(attributes: Mapping[str, Mapping[str, Any]] | None) -> set[str]:
    """The names of the valid attributes of a record (``None``: an old record, nothing known)."""
    if attributes is None:
        return set()
    return {a for a in ATTRIBUTES if a in attributes and bool(attributes[a].get("valid"))}


def valid_everywhere(tile_metas: Sequence[Mapping[str, Any]]) -> list[str] | None:
    """The attributes valid on the block of every tile (their ``valid_attributes``): what a
    model trained on them may read. Present is not enough: an intensity all 0 teaches a model
    nothing it can use. ``None`` when a tile was written before the attributes were recorded."""
    if not tile_metas or any("valid_attributes" not in m for m in tile_metas):
        return None
    return sorted(set.intersection(*(set(m["valid_attributes"]) for m in tile_metas)))


def describe(attributes: Mapping[str, Mapping[str, Any]]) -> str:
    """One line: ``intensity ok; returns: return numbers all 0; rgb ok; nir: not in the point format``."""
    return "; ".join(
        f"{a} ok" if attributes[a]["valid"] else f"{a}: {attributes[a]['reason']}"
        for a in ATTRIBUTES
        if a in attributes
    )
