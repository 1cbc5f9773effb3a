"""The preprocessing's parameters (:class:`PreprocessConfig`, the ``preprocess:`` section of the config)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass
class PreprocessConfig:
    """Parameters of the preprocessing (the ``preprocess:`` section of the config).

    Attributes
    ----------
    tile_size
        Side of a tile in metres.
    buffer
        Buffer around a tile core in metres (at least one window).
    dtm_resolution
        DTM cell size in metres.
    hag_max
        Points higher above ground are noise (paper: 100 m).
    hag_min
        Points lower than this below the DTM are noise (low outliers).
    min_ground_fraction
        Below this share of class-2 points, ground is classified with PDAL.
    ground_filter
        ``"smrf"`` or ``"csf"``.
    outlier
        Run PDAL's statistical outlier filter (slow: superlinear in PDAL 2.2).
    """

    tile_size: float = 500.0
    buffer: float = 40.0
    dtm_resolution: float = 1.0
    hag_max: float = 100.0
    hag_min: float = -2.0
    min_ground_fraction: float = 0.02
    ground_filter: str = "smrf"
    outlier: bool = False
    outlier_mean_k: int = 8
    outlier_multiplier: float = 3.0

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> "PreprocessConfig":
        d = dict(d or {})
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})
