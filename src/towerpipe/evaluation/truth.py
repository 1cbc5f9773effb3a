"""What a labelled zone's towers truly are: its truth file, or the points its blocks label 15.

:func:`zone_truth` gives the true towers (a generated zone's
:data:`towerpipe.synth.truth.TRUTH_GPKG`, else the towers an agency's own labelled blocks make), and
:func:`zone_labels` them and each block's labelled points from one read of the blocks;
:mod:`towerpipe.evaluation.calibrate`, :mod:`~towerpipe.evaluation.trace`,
:mod:`~towerpipe.evaluation.evaluate` and :mod:`~towerpipe.evaluation.realshape` score against them.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe import classes
from towerpipe.errors import InputError

__all__ = ["zone_labels", "zone_truth"]


def zone_truth(
    input_dir: str | os.PathLike[str], truth_file: str | os.PathLike[str] | None = None, *, min_points: int = 1
):
    """The true towers of a zone: its truth file, else the towers its blocks label 15.

    A generated zone has :data:`towerpipe.synth.truth.TRUTH_GPKG`; an agency's own labelled
    blocks have only their class 15, whose points are clustered into towers as the QA pages
    cluster them (:func:`towerpipe.towers.matching.towers_from_labels`, every labelled point, all blocks
    together so that a tower across an edge is one; towers whose crossarms touch stay one).

    Parameters
    ----------
    input_dir
        The zone's input directory.
    truth_file
        A truth GeoPackage (layer ``towers``) to use instead; it must exist.
    min_points
        Labelled clusters with fewer points are no towers (as the QA pages take
        ``towers.min_points``): a stray labelled point beside a tower is not a tower of its own
        that a prediction could match. Not applied to a truth file.

    Returns
    -------
    geopandas.GeoDataFrame
        ``tower_id``, ``n_points`` and the footprint of each true tower (a truth file's own columns).
    """
    truth = _truth_file(input_dir, truth_file)
    return truth if truth is not None else _truth_from_labels(input_dir, _read_labelled(input_dir), min_points)


def zone_labels(
    input_dir: str | os.PathLike[str], truth_file: str | os.PathLike[str] | None = None, *, min_points: int = 1
) -> tuple[Any, dict[str, np.ndarray]]:
    """:func:`zone_truth` of a zone and, by block name, the indices of its points labelled 15 in the
    input, the blocks read once for both."""
    truth = _truth_file(input_dir, truth_file)
    labelled = _read_labelled(input_dir)
    if truth is None:
        truth = _truth_from_labels(input_dir, labelled, min_points)
    return truth, {name: idx for name, (idx, _) in labelled["blocks"].items()}


def _truth_file(input_dir: str | os.PathLike[str], truth_file: str | os.PathLike[str] | None):
    """The zone's truth GeoPackage read (``None`` when an unnamed one is absent)."""
    import geopandas as gpd

    from towerpipe.synth.truth import TRUTH_GPKG

    path = Path(truth_file) if truth_file else Path(input_dir) / TRUTH_GPKG
    if path.exists():
        return gpd.read_file(path, layer="towers")
    if truth_file:
        raise InputError(path, "no such truth file")
    return None


def _read_labelled(input_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """Each block's points labelled 15: ``{"blocks": {name: (indices, xyz)}, "crs": ...}``, a block
    read chunk by chunk."""
    import laspy

    from towerpipe.io.inputs import find_blocks
    from towerpipe.io.las import laz_backend

    out: dict[str, Any] = {"blocks": {}, "crs": None}
    for name, path in find_blocks(input_dir).items():
        idx, xyz, start = [], [], 0
        with laspy.open(path, laz_backend=laz_backend()) as f:
            out["crs"] = out["crs"] or f.header.parse_crs()
            for chunk in f.chunk_iterator(2_000_000):
                tower = np.flatnonzero(np.asarray(chunk.classification) == classes.TOWER)
                idx.append(tower + start)
                xyz.append(np.column_stack([np.asarray(getattr(chunk, k))[tower] for k in "xyz"]))
                start += len(chunk)
        out["blocks"][name] = (
            np.concatenate(idx) if idx else np.empty(0, np.int64),
            np.concatenate(xyz) if xyz else np.empty((0, 3)),
        )
    return out


def _truth_from_labels(input_dir: str | os.PathLike[str], labelled: Mapping[str, Any], min_points: int):
    """The towers the blocks' class-15 points make (:func:`zone_truth` without a truth file)."""
    from towerpipe.synth.truth import TRUTH_GPKG
    from towerpipe.towers.matching import towers_from_labels

    parts = [xyz for _, xyz in labelled["blocks"].values()]
    xyz = np.concatenate(parts) if parts else np.empty((0, 3))
    if not len(xyz):
        raise InputError(
            input_dir,
            f"no {TRUTH_GPKG} and no point labelled {classes.TOWER} in any block: nothing to score against",
        )
    ones = np.ones(len(xyz), bool)
    return towers_from_labels(
        xyz[:, 0], xyz[:, 1], xyz[:, 2], None, ones, min_points=int(min_points), crs=labelled["crs"]
    )
