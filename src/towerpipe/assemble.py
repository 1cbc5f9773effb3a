"""Assembling a zone's result directory from per-block products.

The zone directory is rebuilt in a temporary sibling from hard links (copies
where the file system refuses links) and swapped in with a rename, so readers
never see a half-refreshed zone and adding a block only adds links. Single files
(QA pages, JSON summaries) are written the same way with :func:`write_text_atomic`.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` via a fixed-name hidden temporary (``.<name>.part``) and a rename.

    Readers never see a half-written file, and a rerun after a kill replaces a stale temporary.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
    return path


def link_or_copy(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """Hard-link ``src`` to ``dst`` (copy if linking is not possible)."""
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def assemble_directory(out_dir: str | os.PathLike[str], files: Mapping[str, str | os.PathLike[str]],
                       build: Callable[[Path], None] | None = None) -> Path:
    """Atomically (re)build ``out_dir``.

    Parameters
    ----------
    out_dir
        The directory to produce (e.g. ``results/zone1``).
    files
        Relative destination path → source file to link in.
    build
        Called with the temporary directory after linking, to write zone-level
        files (GeoPackage, QA index…) in place.
    """
    out = Path(out_dir.rstrip("/") if isinstance(out_dir, str) else out_dir)
    tmp = out.with_name(out.name + ".part")
    old = out.with_name(out.name + ".old")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for rel, src in sorted(files.items()):
        link_or_copy(src, tmp / rel)
    if build is not None:
        build(tmp)
    shutil.rmtree(old, ignore_errors=True)
    if out.exists():
        os.replace(out, old)
    os.replace(tmp, out)
    shutil.rmtree(old, ignore_errors=True)
    return out
