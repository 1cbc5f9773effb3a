"""The layout of a zone's working directory, ``<workdir>/<zone>/``: defined here once.

The workflow's rules write their intermediates at these places (``workflow/rules/common.smk``
builds its paths from them), and the tools that read a zone's last run (calibration, the
trace, the benchmarks) find them with :func:`zone_files`. A zone run in batches
(:mod:`towerpipe.preprocess.batches`) keeps the same layout inside each batch's directories:
``batches/<batch>/split/`` holds the :data:`CACHE` of its blocks, ``batches/<batch>/infer/``
their :data:`TILE`, :data:`DTM`, :data:`PRED` and :data:`WIRES`, ``batches/<batch>/products/``
their :data:`TOWERS_GPKG` … :data:`QA_JSON`.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable
from pathlib import Path

#: Per-block intermediates, relative to ``<workdir>/<zone>/`` or to a batch's directory.
CACHE = "cache/{block}"
TILE = "tiles/{block}/{tile}.npz"
DTM = "dtm/{block}/{tile}.tif"
PRED = "pred/{block}/{tile}.npz"
WIRES = "wires/{block}/{tile}.npz"
TOWERS_GPKG = "towers/{block}.gpkg"
TOWERS_NEIGHBOURS = "towers/{block}.neighbours.json"
TOWER_MEMBERS = "towers/{block}.points.npz"
BLOCK_LAZ = "out/{block}.laz"
QA_HTML = "qa/{block}.html"
QA_JSON = "qa/{block}.json"

#: A batch's directories (rules ``split_batch``, ``infer_batch`` and ``products_batch``), relative to
#: ``<workdir>/<zone>/``.
BATCH_SPLIT = "batches/{batch}/split"
BATCH_INFER = "batches/{batch}/infer"
BATCH_PRODUCTS = "batches/{batch}/products"
#: A block's time at one stage of its batch (a Snakemake benchmark TSV), relative to the batch's directory.
BATCH_TIMING = "timings/{block}.{stage}.tsv"


#: A block's intermediates (relative to ``<workdir>/<zone>/`` or to a batch's directory): what a
#: block that left the zone leaves behind (:func:`gone_blocks`).
PER_BLOCK = (CACHE, TILE, DTM, PRED, WIRES, TOWERS_GPKG, TOWERS_NEIGHBOURS, TOWER_MEMBERS, BLOCK_LAZ, QA_HTML, QA_JSON)
#: The per-job logs and benchmarks of a zone, ``<rule>/<block>.log`` or ``<rule>/<block>/<tile>.log``
#: under these (``log_of`` and ``benchmark_of`` of ``workflow/rules/common.smk``).
LOGS, BENCHMARKS = "logs", "benchmarks"
JOB_RECORDS = (LOGS, BENCHMARKS)


def gone_blocks(zone_dir: str | os.PathLike[str], blocks: Iterable[str]) -> dict[str, list[Path]]:
    """The intermediates a zone's working directory keeps of blocks no longer in the zone.

    Parameters
    ----------
    zone_dir
        ``<workdir>/<zone>/``.
    blocks
        The zone's blocks now (every input file's block id, failed ones included).

    Returns
    -------
    dict
        Block → its files and folders (:data:`PER_BLOCK`, in the zone's directory and in
        each batch's, and its jobs' :data:`JOB_RECORDS`), for every block that has some
        and is not in ``blocks``.
    """
    root, keep = Path(zone_dir), set(blocks)
    bases = [
        root,
        *(d for b in (BATCH_SPLIT, BATCH_INFER, BATCH_PRODUCTS) for d in sorted(root.glob(b.format(batch="*")))),
    ]
    gone: dict[str, list[Path]] = {}
    for base in bases:
        for pattern in PER_BLOCK:
            head, tail = pattern.split("{block}", 1)
            folder = base / head
            if not folder.is_dir():
                continue
            if not tail or tail.startswith("/"):  # a folder per block
                found = [(p.name, p) for p in folder.iterdir() if p.is_dir()]
            else:  # files named by the block
                found = [(p.name[: -len(tail)], p) for p in folder.glob(f"*{tail}") if p.is_file()]
            for block, path in found:
                if block not in keep:
                    gone.setdefault(block, []).append(path)
    for records in JOB_RECORDS:
        for rule_dir in sorted(p for p in (root / records).glob("*") if p.is_dir()):
            for path in rule_dir.iterdir():
                block = path.name if path.is_dir() else path.name.rsplit(".", 1)[0]
                if block in gone:  # a batch's records are named by the batch: never a gone block's
                    gone[block].append(path)
    return gone


def remove_gone_blocks(zone_dir: str | os.PathLike[str], blocks: Iterable[str]) -> dict[str, int]:
    """Delete what :func:`gone_blocks` finds; returns block → bytes freed."""
    freed: dict[str, int] = {}
    for block, paths in gone_blocks(zone_dir, blocks).items():
        for path in paths:
            files = [path] if path.is_file() else [f for f in path.rglob("*") if f.is_file()]
            freed[block] = freed.get(block, 0) + sum(f.stat().st_size for f in files)
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink()
    return freed


def zone_files(work: str | os.PathLike[str], zone: str, pattern: str) -> list[Path]:
    """Every file of a per-block ``pattern`` (:data:`TILE`, :data:`PRED` …) of a zone's last
    run, whether its blocks ran one by one or in batches (sorted by block, then tile)."""
    glob = pattern.format(block="*", tile="*")
    root = Path(work, zone)
    found = list(root.glob(glob))
    for batch_dir in (BATCH_SPLIT, BATCH_INFER, BATCH_PRODUCTS):
        found += root.glob(f"{batch_dir.format(batch='*')}/{glob}")
    return sorted(found, key=lambda p: (p.parent.name, p.name) if "{tile}" in pattern else (p.name,))


def block_cache(made_by: str | os.PathLike[str], block: str) -> Path:
    """A block's split cache (:data:`CACHE`), from what made it: the cache itself (a split job of
    its own), or its split batch's directory (:data:`BATCH_SPLIT`), which holds it."""
    path = Path(made_by)
    if path.parent.name == Path(CACHE).parent.name:  # .../cache/<block>
        return path
    return path / CACHE.format(block=block)


def conductors_of(tile: str | os.PathLike[str]) -> Path:
    """Where the inference job of a tile (:data:`TILE`) writes its conductor points (:data:`WIRES`):
    beside it, in the same zone's or batch's directory."""
    path = Path(tile)
    root = path.parents[len(Path(TILE).parts) - 1]
    return root / WIRES.format(block=path.parent.name, tile=path.stem)
