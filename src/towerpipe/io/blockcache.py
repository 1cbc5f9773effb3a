"""The block cache: a split block's decoded columns, raw point records and metadata.

The split (:func:`towerpipe.preprocess.split.split_block`) decodes a block once into
a directory that every later step reads instead of the LAZ. This module owns its
layout, and everything that reads or writes a cache goes through :class:`BlockCache`:

* ``{column}.npy`` for each of :data:`towerpipe.io.las.BLOCK_COLUMNS` (memory-mapped
  by the tiles, the QA and the model choice);
* :data:`RECORDS_FILE`, the block's point records as decoded (``(points, record size)``
  uint8), so that the merge copies them without decoding the LAZ a second time;
* :data:`CACHE_META` (``meta.json``): what the split measured, or the error of a block
  that could not be split (then the only file).

A cache is written to a ``<dir>.part`` sibling and renamed when complete
(:meth:`BlockCache.create`), so a crash leaves nothing that looks complete.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.errors import InputError, TowerpipeError

#: The cache's metadata file (JSON).
CACHE_META = "meta.json"

#: File of a block cache holding the block's point records as decoded (``(points, record
#: size)`` uint8): the merge copies them instead of decoding the LAZ a second time.
RECORDS_FILE = "records.npy"

#: dtype of each cache column; columns not named here are ``u2`` (intensity, colour, NIR).
COLUMN_DTYPES = {
    "x": "f8",
    "y": "f8",
    "z": "f8",
    "classification": "u1",
    "return_number": "u1",
    "number_of_returns": "u1",
}


def column_file(name: str) -> str:
    """The file name of cache column ``name``."""
    return f"{name}.npy"


class _NpyStream:
    """Write one ``.npy`` array chunk by chunk: the header for the final shape, then the data."""

    def __init__(self, path: Path, dtype: str, shape: tuple[int, ...]):
        self.path, self.dtype, self.shape = path, np.dtype(dtype), shape
        self.fh = open(path, "wb")
        np.lib.format.write_array_header_1_0(
            self.fh, {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False, "shape": shape}
        )
        self.rows = 0

    def write(self, a: np.ndarray) -> None:
        a = np.ascontiguousarray(a, dtype=self.dtype)
        if a.shape[1:] != self.shape[1:] or self.rows + len(a) > self.shape[0]:
            raise TowerpipeError(f"{self.path}: chunk {a.shape} does not fit the array {self.shape}")
        self.fh.write(a.data)
        self.rows += len(a)

    def close(self) -> None:
        self.fh.close()


def _staging_dir(out_dir: str | os.PathLike[str]) -> Path:
    """An empty ``<out_dir>.part`` sibling to write a cache into (a stale one is removed)."""
    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + ".part")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    return tmp


def _publish_dir(tmp: Path, out_dir: str | os.PathLike[str]) -> None:
    """Replace ``out_dir`` by the finished staging directory ``tmp``."""
    shutil.rmtree(out_dir, ignore_errors=True)
    os.replace(tmp, out_dir)


class BlockCacheWriter:
    """A cache being written (in its staging directory): see :meth:`BlockCache.create`."""

    def __init__(self, directory: Path):
        self.directory = directory

    def column_writer(self, name: str, n: int) -> _NpyStream:
        """A stream of ``n`` values of column ``name`` (``.write(chunk)`` in order, then ``.close()``).

        Streamed (header first, then each chunk appended): the cache never sits in the
        writer's memory.
        """
        return _NpyStream(self.directory / column_file(name), COLUMN_DTYPES.get(name, "u2"), (n,))

    def records_writer(self, n: int, record_size: int) -> _NpyStream:
        """A stream of the ``n`` raw point records (:data:`RECORDS_FILE`)."""
        return _NpyStream(self.directory / RECORDS_FILE, "u1", (n, record_size))

    def column(self, name: str) -> np.ndarray:
        """A column written so far, memory-mapped (its stream closed)."""
        return np.load(self.directory / column_file(name), mmap_mode="r")

    def write_meta(self, meta: Mapping[str, Any]) -> None:
        """Write :data:`CACHE_META`."""
        (self.directory / CACHE_META).write_text(json.dumps(meta, indent=1))


class ColumnReader:
    """A cache column read a piece at a time: ``reader[key]`` is a copy, taken through a mapping
    of the file made for that read and released with it.

    A mapping kept open keeps every page it has touched in the process's memory, so a job that
    goes through a block chunk by chunk on a memory-mapped column ends up holding the whole
    column (on a km² at 20 pts/m², x, y and z are 470 MB); through a reader it holds a chunk.
    ``np.asarray(reader)`` reads the whole column.
    """

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        whole = np.load(self.path, mmap_mode="r")
        self.shape, self.dtype = whole.shape, whole.dtype

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        return np.array(np.load(self.path, mmap_mode="r")[key])

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        whole = np.load(self.path)
        return whole if dtype is None else whole.astype(dtype, copy=False)


class BlockCache:
    """A split block's cache directory: metadata and memory-mapped columns.

    ``BlockCache(directory)`` reads nothing; :meth:`open` reads and checks the metadata.
    """

    def __init__(self, directory: str | os.PathLike[str], meta: dict[str, Any] | None = None):
        self.directory = Path(directory)
        self._meta = meta

    @classmethod
    def open(cls, directory: str | os.PathLike[str], *, allow_failed: bool = False) -> BlockCache:
        """Open a cache; a cache that records a failed split raises that block's error.

        With ``allow_failed`` it is returned instead (check :attr:`failed`).
        """
        cache = cls(directory)
        err = cache.meta.get("error")
        if err and not allow_failed:
            raise InputError(err["path"], err["cause"])
        return cache

    @classmethod
    @contextlib.contextmanager
    def create(cls, out_dir: str | os.PathLike[str]) -> Iterator[BlockCacheWriter]:
        """Write a cache: a writer on a staging directory that replaces ``out_dir`` on
        success and is removed on any failure."""
        tmp = _staging_dir(out_dir)
        try:
            yield BlockCacheWriter(tmp)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        _publish_dir(tmp, out_dir)

    @property
    def meta_path(self) -> Path:
        """The metadata file (:data:`CACHE_META`)."""
        return self.directory / CACHE_META

    @property
    def records_path(self) -> Path:
        """The raw point records (:data:`RECORDS_FILE`; absent in a cache of a failed block)."""
        return self.directory / RECORDS_FILE

    def column_path(self, name: str) -> Path:
        """The file of column ``name``."""
        return self.directory / column_file(name)

    def exists(self) -> bool:
        """Whether the split wrote this cache (its metadata exists; it may record an error)."""
        return self.meta_path.exists()

    def read_meta(self) -> dict[str, Any]:
        """The metadata as written, read afresh (``OSError``/``ValueError`` as raised)."""
        return json.loads(self.meta_path.read_text())

    @property
    def meta(self) -> dict[str, Any]:
        """The metadata (read once; an unreadable cache raises :class:`InputError`)."""
        if self._meta is None:
            try:
                self._meta = self.read_meta()
            except (OSError, ValueError) as exc:
                raise InputError(self.directory, f"block cache unreadable ({exc}); rerun the split_block job") from exc
        return self._meta

    @property
    def failed(self) -> str | None:
        """The one-line error of a block that could not be split, else ``None``."""
        err = self.meta.get("error")
        return f"{err['type']}: {err['path']}: {err['cause']}" if err else None

    def column(self, name: str, *, mmap: bool = True) -> np.ndarray:
        """Column ``name`` loaded afresh: memory-mapped read-only, or in memory with ``mmap=False``."""
        return np.load(self.column_path(name), mmap_mode="r" if mmap else None)

    def reader(self, name: str) -> ColumnReader:
        """Column ``name`` read a piece at a time (:class:`ColumnReader`)."""
        return ColumnReader(self.column_path(name))
