"""Typed column arrays plus JSON metadata in one uncompressed ``.npz``, written atomically.

The format shared by the intermediate files (:mod:`towerpipe.io.tiles`,
:mod:`towerpipe.io.predictions`): one array per column, all the same length, with
dtypes fixed by a schema, and a ``meta`` member holding JSON. Uncompressed,
because compressed intermediates cost more time than they save disk.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.errors import InputError


def validate_columns(
    arrays: Mapping[str, np.ndarray], schema: Mapping[str, np.dtype], path: str | os.PathLike[str], what: str, hint: str
) -> int:
    """Check names, dtypes and lengths against ``schema``; return the length.

    Raises
    ------
    InputError
        Naming ``path``, the ``what`` array at fault and the ``hint`` (what to rerun).
    """
    missing = sorted(set(schema) - set(arrays))
    if missing:
        raise InputError(path, f"{what} file lacks arrays {missing}; {hint}")
    first = next(iter(schema))
    n = len(arrays[first])
    for name, dtype in schema.items():
        arr = arrays[name]
        if arr.shape != (n,):
            raise InputError(path, f"{what} array {name!r} has shape {arr.shape}, expected ({n},)")
        if arr.dtype != dtype:
            raise InputError(path, f"{what} array {name!r} is {arr.dtype}, expected {dtype}")
    return n


def save_columns(path: str | os.PathLike[str], arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> None:
    """Write ``arrays`` and ``meta`` to ``path`` via ``<path>.part`` and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.frombuffer(json.dumps(dict(meta)).encode(), dtype=np.uint8), **arrays)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def load_columns(
    path: str | os.PathLike[str], names: list[str], what: str, hint: str
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read the ``names`` arrays and the metadata of a file written by :func:`save_columns`."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            arrays = {k: z[k] for k in names}
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(path, f"not a readable towerpipe {what} file ({exc}); {hint}") from exc
    return arrays, meta


def read_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Only the metadata of a column file (the arrays are not read)."""
    with np.load(path, allow_pickle=False) as z:
        return json.loads(bytes(z["meta"]).decode())
