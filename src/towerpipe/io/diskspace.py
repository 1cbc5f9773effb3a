"""Disk space: a check before a block's work files are written, and a plain error when a disk fills.

A block's files in the working directory take about :data:`WORK_BYTES_PER_POINT` bytes per
input point: its column cache (79 bytes a point), its tiles with their buffers (63-76), its
classified LAZ (10) and the rest (predictions, DTMs, wires, towers: under 3). Measured on
``calib``, ``holdout2`` and the demo zone (160-169 bytes a point in all); the published
products (``results/<zone>/``) are hard links to the same files where they share the disk.
A block of 1 km² at 10 points a m² thus holds about 1.7 GB of the working directory for as
long as the directory is kept.

:func:`require_free` refuses a block before its split when its disk has less room than that
(:func:`towerpipe.preprocess.split.split_block`), so a run stops at once with a message that
names the directory, instead of hours later with a file cut short. :func:`full_disk_error` turns
an ``OSError`` of a full disk (``ENOSPC``, ``EDQUOT``) raised anywhere in a job into a
:class:`~towerpipe.errors.DiskSpaceError` (:func:`towerpipe.jobs.smk.run_step`), and
:func:`raise_if_full` gives one where another program (PDAL) failed or cut a file short on a
full disk (:mod:`towerpipe.preprocess.pdal`).
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path

from towerpipe.errors import DiskSpaceError

__all__ = [
    "LOW_SPACE_BYTES",
    "MOVE_FIX",
    "WORK_BYTES_PER_POINT",
    "free_bytes",
    "full_disk_error",
    "raise_if_full",
    "require_free",
]

#: Bytes a block's files take in the working directory per input point (see the module docstring).
WORK_BYTES_PER_POINT = 170
#: Room (bytes) always left free on top of what a block needs: the logs, Snakemake's metadata,
#: PDAL's temporary files of a tile. Under this, a disk counts as full.
LOW_SPACE_BYTES = 256 * 2**20
#: Where a job's files go, and how to send them to another disk (the end of every message).
MOVE_FIX = "point `workdir` in the config (the work files) or TMPDIR (PDAL's temporary files) at a larger disk"

_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
#: What a full disk says through libraries that re-raise it as text (the LAZ codec, PDAL).
_FULL_TEXT = ("No space left on device", "Disk quota exceeded")


def _existing(path: str | os.PathLike[str]) -> Path:
    """``path`` or its nearest existing ancestor (a directory not created yet is on its parent's disk)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def free_bytes(path: str | os.PathLike[str]) -> int | None:
    """Bytes free for this user on the disk that holds ``path`` (or would hold it); ``None``
    where the system does not say."""
    try:
        return int(shutil.disk_usage(_existing(path)).free)
    except OSError:
        return None


def require_free(path: str | os.PathLike[str], needed: int, *, what: str, fix: str) -> None:
    """Raise :class:`DiskSpaceError` when the disk of ``path`` has less than ``needed`` bytes
    free besides :data:`LOW_SPACE_BYTES`.

    Parameters
    ----------
    path
        Where the files will be written (it need not exist yet).
    needed
        Bytes they will take.
    what
        What needs the room, for the message (e.g. ``"block b7 (9,870,000 points)"``).
    fix
        The config key or setting that moves the files elsewhere, for the message.
    """
    free = free_bytes(path)
    if free is None or free >= needed + LOW_SPACE_BYTES:
        return
    raise DiskSpaceError(
        _existing(path),
        f"{what} needs about {_size(needed)} there, {_size(LOW_SPACE_BYTES)} more kept free for logs and temporary "
        f"files, and {_size(free)} is free on that disk; free space on it or {fix}",
    )


def raise_if_full(path: str | os.PathLike[str], *, what: str) -> None:
    """Raise :class:`DiskSpaceError` when the disk of ``path`` has less than
    :data:`LOW_SPACE_BYTES` free: a program that failed to write there (or wrote a file cut
    short) most likely ran out of room. ``what`` says what failed."""
    free = free_bytes(path)
    if free is not None and free < LOW_SPACE_BYTES:
        raise DiskSpaceError(path, f"{what}: the disk is full ({_size(free)} free); free space on it or {MOVE_FIX}")


def full_disk_error(exc: BaseException, *, fix: str = MOVE_FIX) -> DiskSpaceError | None:
    """The :class:`DiskSpaceError` behind ``exc`` when a disk filled up, else ``None``.

    ``exc`` and the exceptions it was raised from (``__cause__``, ``__context__``) are looked
    at: an ``OSError`` with ``ENOSPC`` or ``EDQUOT``, or an error whose text says the disk is
    full. The error names the file that could not be written where the exception does, else
    the fuller of the temporary directory (``TMPDIR``) and the current one.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, DiskSpaceError):  # said already, where it was met
            return e
        full = isinstance(e, OSError) and e.errno in _FULL_ERRNOS
        if full or any(t in str(e) for t in _FULL_TEXT):
            # the file where the error names it, else the fuller of the temporary and current directories
            named = getattr(e, "filename", None)
            where = named or min((tempfile.gettempdir(), os.getcwd()), key=lambda d: free_bytes(d) or 0)
            free = free_bytes(where)
            left = f"{_size(free)} free" if free is not None else "its free space unknown"
            return DiskSpaceError(where, f"the disk is full ({left}: {e}); free space on it or {fix}")
        e = e.__cause__ or e.__context__
    return None


def _size(n: int | float) -> str:
    """``n`` bytes as MiB under a GiB, else GiB, one decimal."""
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"
