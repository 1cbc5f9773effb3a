"""A zone's input files: safe block ids and content fingerprints.

Every ``.las``/``.laz`` file under a zone's input directory is one block (hidden files and
folders, whose name starts with ``.``, are not: :func:`find_blocks`). Its **block
id** names its jobs and products (``results/<zone>/blocks/<id>.laz``), so it must be a
safe file name and unique in the zone, whatever the file is called:

* the id is the path relative to the input directory, without the suffix, with ``/``
  replaced by ``__`` (``flight1/a.laz`` → ``flight1__a``), when that is made of ASCII
  letters, digits, ``_``, ``.`` and ``-`` only and no other file gives the same id;
* otherwise (spaces, braces, non-ASCII letters, ``flight1/a.laz`` beside
  ``flight1__a.laz``, ``a.las`` beside ``a.laz``) every other character becomes ``_``
  and ``-`` plus 8 hex digits of the relative path's SHA-1 are appended
  (``blk{1}.laz`` → ``blk_1_-5d41402a``). The original relative path is kept in
  every product (cache meta, block summary, GeoPackage ``source_files``, QA).

Two files that differ only in their LAS suffix (``a.las``, ``a.laz``) are one block
twice: :attr:`BlockInput.clash` names the other file, and the split refuses both (a
clash costs those blocks, never the zone).

A block's **fingerprint** (:func:`fingerprint`) is the SHA-256 of all its bytes (about
0.25 s for a 440 MB LAS on one core). It is a parameter of the block's split job, so a file
replaced or edited in place reruns the block's jobs whatever its modification time
(``cp -p``, ``rsync -a`` from an archive), and a file only touched reruns nothing.
Fingerprints are cached by the file's ``stat`` (device, inode, size, mtime, ctime: a
rewritten file always gets a new ctime), so planning a zone of thousands of blocks reads
only new or changed files. A cache record of the earlier, sampled recipe (version 1: the
size, the first and last MiB and 16 slices of 64 KiB, which missed an edit between the
slices of an uncompressed file) is kept while its file's ``stat`` holds, so that an upgrade
reruns no block; once the file changes it is read whole.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import unicodedata
from collections import defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from towerpipe.errors import TowerpipeError

LAS_SUFFIXES = (".las", ".laz")

#: Characters a block id may hold (besides a leading letter, digit or ``_``).
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")
#: Version of the fingerprint recipe (part of every fingerprint: a new recipe reruns the files it reads).
FINGERPRINT_VERSION = 2
#: Cache records of these earlier recipes stand while their file's ``stat`` is unchanged.
_KEPT_VERSIONS = (1, FINGERPRINT_VERSION)


@dataclass(frozen=True)
class BlockInput:
    """One input file of a zone.

    Attributes
    ----------
    id
        The safe, unique block id.
    path
        The file.
    relpath
        Its path relative to the zone's input directory (as the user named it).
    size
        Bytes.
    fingerprint
        Content fingerprint (:func:`fingerprint`).
    header
        ``point_count``, ``version``, ``point_format``, ``crs_wkt``, ``bounds`` from the header, or
        ``None`` when the header is unreadable (the split reports why). Header values
        never shape the job graph; they only size job resources and pick the zone's CRS.
    clash
        The other file when this one is the same block in a second file, else ``None``.
    """

    id: str
    path: str
    relpath: str
    size: int
    fingerprint: str
    header: dict[str, Any] | None = None
    clash: str | None = None

    @property
    def points_estimate(self) -> int:
        """Points for sizing resources: the header's count, never more than the file's bytes."""
        n = int((self.header or {}).get("point_count") or 0)
        return min(n, self.size) if n > 0 else self.size // 30


def _stem(rel: str) -> str:
    p = Path(rel)
    return str(p.with_suffix("")) if p.suffix.lower() in LAS_SUFFIXES else rel


def safe_name(rel: str) -> str:
    """The id a relative path gets when it is unique (see the module docstring)."""
    base = "__".join(Path(_stem(rel)).parts)
    letters = "".join(c for c in unicodedata.normalize("NFKD", base) if not unicodedata.combining(c))
    safe = _UNSAFE.sub("_", letters)
    if not safe or not (safe[0].isalnum() or safe[0] == "_"):
        safe = "_" + safe
    return safe


def block_ids(relpaths: list[str]) -> dict[str, str]:
    """Block id → relative path for every input file (ids are unique and safe)."""
    by_safe: dict[str, list[str]] = defaultdict(list)
    for rel in relpaths:
        by_safe[safe_name(rel)].append(rel)
    out: dict[str, str] = {}
    for safe, rels in by_safe.items():
        for rel in rels:
            plain = "__".join(Path(_stem(rel)).parts)
            if len(rels) == 1 and plain == safe:
                out[safe] = rel
            else:
                out[f"{safe}-{hashlib.sha1(rel.encode()).hexdigest()[:8]}"] = rel
    return dict(sorted(out.items()))


def find_blocks(input_dir: str | os.PathLike[str]) -> dict[str, str]:
    """Block id → path of every ``.las``/``.laz`` file under ``input_dir`` (sorted by id).

    Hidden files and folders (a name starting with ``.``) are not blocks: the ``._x.laz``
    that macOS writes beside ``x.laz`` on a network share holds no points, and a folder
    such as ``.snapshot`` holds copies.
    """
    root = Path(input_dir)
    found = (p.relative_to(root) for p in sorted(root.rglob("*")) if p.suffix.lower() in LAS_SUFFIXES)
    rels = [
        rel.as_posix()
        for rel in found
        if not any(part.startswith(".") for part in rel.parts) and (root / rel).is_file()
    ]
    return {b: str(root / rel) for b, rel in block_ids(rels).items()}


def no_blocks_message(zone: str, input_dir: str | os.PathLike[str]) -> str:
    """What an operator reads when a zone's input directory holds no block."""
    return f"zones.{zone}.input: no .las/.laz files under {str(input_dir)!r}"


def fingerprint(path: str | os.PathLike[str]) -> str:
    """Content fingerprint of a file (see the module docstring): 24 hex digits of the SHA-256
    of the recipe's version and every byte."""
    h = hashlib.sha256(f"towerpipe-fingerprint-{FINGERPRINT_VERSION}".encode())
    with open(path, "rb") as fh:
        h.update(hashlib.file_digest(fh, "sha256").digest())
    return h.hexdigest()[:24]


def _stat_key(st: os.stat_result) -> list[int]:
    return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]


def _header(path: str) -> dict[str, Any] | None:
    from towerpipe.io.las import read_header

    try:
        h = read_header(path)
    except TowerpipeError:
        return None
    return {
        "point_count": h.point_count,
        "version": h.version,
        "point_format": h.point_format,
        "crs_wkt": h.crs_wkt,
        "bounds": [float(v) for v in h.bounds],
    }


def scan_zone(input_dir: str | os.PathLike[str], cache: str | os.PathLike[str] | None = None) -> dict[str, BlockInput]:
    """Every block of a zone with its fingerprint (id → :class:`BlockInput`, sorted by id).

    Parameters
    ----------
    input_dir
        The zone's input directory.
    cache
        JSON file keeping fingerprints and headers by ``stat`` between runs; files whose
        ``stat`` is unchanged are not read again. Written atomically when it changes.
    """
    from towerpipe.io.atomic import write_text_atomic

    paths = find_blocks(input_dir)
    root = Path(input_dir)
    known: dict[str, Any] = {}
    if cache is not None and Path(cache).is_file():
        try:
            known = json.loads(Path(cache).read_text())
        except ValueError:
            known = {}
    fresh: dict[str, Any] = {}
    out: dict[str, BlockInput] = {}
    stems: dict[str, list[str]] = defaultdict(list)
    for b, p in paths.items():
        stems[_stem(Path(p).relative_to(root).as_posix())].append(b)
    for b, p in paths.items():
        rel = Path(p).relative_to(root).as_posix()
        key = _stat_key(os.stat(p))
        rec = known.get(rel)
        if not rec or rec.get("stat") != key or rec.get("version") not in _KEPT_VERSIONS:
            rec = {"stat": key, "version": FINGERPRINT_VERSION, "fingerprint": fingerprint(p), "header": _header(p)}
        fresh[rel] = rec
        twins = [paths[o] for o in stems[_stem(rel)] if o != b]
        out[b] = BlockInput(
            b,
            p,
            rel,
            key[2],
            rec["fingerprint"],
            rec["header"],
            Path(twins[0]).relative_to(root).as_posix() if twins else None,
        )
    if cache is not None and fresh != known:
        write_text_atomic(cache, json.dumps(fresh, indent=0, sort_keys=True))
    return out


#: Why a file of zero points is listed and not run (the zone's QA index).
EMPTY_REASON = "the file holds zero points: nothing to process; skipped while it is in the zone, never a failure"


def is_empty(block: BlockInput) -> bool:
    """A readable LAS/LAZ file whose header counts zero points: a block with nothing to process
    (a sea tile, a tile cut to a boundary). The zone skips it and its QA index lists it; an
    unreadable file (no header) is not empty: its split says what is wrong."""
    return block.header is not None and block.header.get("point_count") == 0


def describe(block: BlockInput) -> dict[str, Any]:
    """JSON-able record of a block input (for the split's metadata)."""
    d = asdict(block)
    d.pop("header")
    return d
