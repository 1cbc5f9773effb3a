"""Assembling a zone's result directory from per-block products.

The zone directory is rebuilt in a hidden staging sibling (``.<name>.staging``) from
hard links (copies where the file system refuses links) and swapped in atomically
(:func:`swap_in`: Linux ``renameat2(RENAME_EXCHANGE)``), so the directory exists at
every moment, readers never see a half-refreshed zone, and the old one is removed only
after the new one is in place. A failure while building (a full disk…) removes the
staging directory and leaves the published one as it was. Single files (QA pages, JSON
summaries) are written the same way with :func:`write_text_atomic`.
"""

from __future__ import annotations

import ctypes
import errno
import os
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` via a fixed-name hidden temporary (``.<name>.part``) and a rename.

    Readers never see a half-written file, and a rerun after a kill replaces a stale temporary.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.part")
    try:
        tmp.unlink(missing_ok=True)
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def link_or_copy(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """Hard-link ``src`` to ``dst`` (copy if linking is not possible)."""
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically; ``False`` where the system cannot (not Linux, old kernel, some network FS)."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, f"renameat2({a}, {b}, RENAME_EXCHANGE): {os.strerror(err)}")


def swap_in(staging: str | os.PathLike[str], out: str | os.PathLike[str]) -> Path:
    """Make the finished directory ``staging`` the new ``out``; the old ``out`` is then removed.

    ``out`` exists at every moment where ``renameat2(RENAME_EXCHANGE)`` is available;
    elsewhere the old directory is moved aside first (a gap of two renames).
    """
    staging, out = Path(staging), Path(out)
    if not out.exists():
        os.replace(staging, out)
        return out
    if _exchange(staging, out):
        shutil.rmtree(staging, ignore_errors=True)  # now the old directory
        return out
    old = out.with_name(f".{out.name}.old")
    shutil.rmtree(old, ignore_errors=True)
    os.replace(out, old)
    os.replace(staging, out)
    shutil.rmtree(old, ignore_errors=True)
    return out


def staging_path(out: str | os.PathLike[str]) -> Path:
    """The hidden sibling a directory is built in before :func:`swap_in`."""
    out = Path(out)
    return out.with_name(f".{out.name}.staging")


def assemble_directory(
    out_dir: str | os.PathLike[str],
    files: Mapping[str, str | os.PathLike[str]],
    build: Callable[[Path], None] | None = None,
) -> Path:
    """Atomically (re)build ``out_dir``, never deleting it first.

    Parameters
    ----------
    out_dir
        The directory to produce (e.g. ``results/zone1``).
    files
        Relative destination path → source file to link in.
    build
        Called with the staging directory after linking, to write zone-level
        files (GeoPackage, QA index…) in place.

    Any failure (a missing product, a full disk) removes the staging directory and
    leaves ``out_dir`` as it was.
    """
    out = Path(str(out_dir).rstrip("/"))
    tmp = staging_path(out)
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
        for rel, src in sorted(files.items()):
            link_or_copy(src, tmp / rel)
        if build is not None:
            build(tmp)
        return swap_in(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def publish_copy(src_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str]) -> Path:
    """Atomically make ``out_dir`` a hard-linked copy of the directory ``src_dir``."""
    src = Path(src_dir)
    files = {p.relative_to(src).as_posix(): p for p in sorted(src.rglob("*")) if p.is_file()}
    return assemble_directory(out_dir, files)
