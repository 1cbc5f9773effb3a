"""The jobs of a batch of small blocks (:mod:`towerpipe.preprocess.batches`): its split, its
inference and its products.

Each calls the per-block steps of :mod:`towerpipe.jobs.steps` block after block, with the
arguments the per-block jobs get, and writes their files into the batch's directory in the
zone's layout (:mod:`towerpipe.io.workdir`): one process and one import of the libraries for
the whole batch instead of one per block and job. The workflow builds the per-tile and
per-block arguments (``batch_tiles`` and ``batch_blocks_args`` in ``workflow/rules/common.smk``).

A block that cannot be read fails alone: its split batch records the error in the block's cache,
as the split job of one block does, and the block is in no inference or products batch. A
block that fails in its batch otherwise (a crash; a zone whose model cannot run on a block runs
block by block) fails its batch job: the job's log
names the block, and the zone is published INCOMPLETE without the batch's blocks, as for any
failed job.

A batch's directory is built in a hidden sibling and moved into place once complete
(:func:`towerpipe.io.atomic.assemble_directory`): a run killed midway leaves no directory that
looks made (Snakemake's mark of an incomplete output does not bring back a directory of a job
planned after a checkpoint), and the next run makes it again.

A block's time in its batch is written beside its files (:data:`towerpipe.io.workdir.BATCH_TIMING`,
a Snakemake benchmark TSV: seconds, and the job's peak memory so far), so its QA page reports the
time of each of its stages as for a block with jobs of its own.
"""

from __future__ import annotations

import logging
import os
import resource
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from towerpipe.io import workdir
from towerpipe.io.atomic import assemble_directory

if TYPE_CHECKING:
    from towerpipe.config import InferenceConfig, PreprocessConfig
    from towerpipe.products.qa.metrics import Limits

log = logging.getLogger(__name__)


def _out(root: str | os.PathLike[str], pattern: str, **names: str) -> str:
    """``root/pattern`` with ``names``, its folder created (a directory output is created empty)."""
    path = Path(root, pattern.format(**names))
    path.parent.mkdir(parents=True, exist_ok=True)
    return str(path)


@contextmanager
def _naming(block: str) -> Iterator[None]:
    """Log which block of the batch an error comes from (the job's log then gives its reason)."""
    try:
        yield
    except Exception:
        log.error("block %s failed: its batch fails with it", block)
        raise


def write_timing(path: str | os.PathLike[str], seconds: float) -> None:
    """A Snakemake benchmark TSV of one row: ``seconds``, and the process's peak memory so far (MB)."""
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    h, rem = divmod(int(seconds), 3600)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(f"s\th:m:s\tmax_rss\n{seconds:.4f}\t{h}:{rem // 60:02d}:{rem % 60:02d}\t{rss_mb:.2f}\n")


def _build(out_dir: str | os.PathLike[str], build: Callable[[Path], None], what: str, count: int) -> dict[str, Any]:
    """Make a batch's directory with ``build`` (in a hidden sibling, moved into place when
    complete: :func:`towerpipe.io.atomic.assemble_directory`) and log its time; ``{what: count}``."""
    t0 = time.perf_counter()
    assemble_directory(out_dir, {}, build)
    log.info("batch of %d %s in %.1f s", count, what, time.perf_counter() - t0)
    return {what: count}


def timing_file(batch_dir: str | os.PathLike[str], block: str, stage: str) -> str:
    """Where the jobs of a batch record a block's ``stage``."""
    return str(Path(batch_dir, workdir.BATCH_TIMING.format(block=block, stage=stage)))


def split_batch(
    zone: str,
    blocks: Sequence[Mapping[str, Any]],
    out_dir: str | os.PathLike[str],
    *,
    settings: PreprocessConfig,
) -> dict[str, Any]:
    """Every block of a split batch, as rule ``split_block`` splits one
    (:func:`towerpipe.preprocess.split.split_block`, errors recorded in the block's cache).

    Parameters
    ----------
    zone
        The zone.
    blocks
        One mapping per block, the arguments of its split: ``block``, ``file``, ``crs`` (the
        zone's ``crs:``, for files without one), ``zone_crs`` and ``source`` (its input record).
    out_dir
        The batch's directory (:data:`towerpipe.io.workdir.BATCH_SPLIT`): each block's
        :data:`~towerpipe.io.workdir.CACHE`.
    settings
        The ``preprocess`` section.
    """
    from towerpipe.preprocess.split import split_block

    def build(out_dir: Path) -> None:
        for spec in blocks:
            b = spec["block"]
            ts = time.perf_counter()
            with _naming(b):
                split_block(
                    spec["file"],
                    _out(out_dir, workdir.CACHE, block=b),
                    block=b,
                    zone=zone,
                    crs=spec["crs"],
                    zone_crs=spec["zone_crs"],
                    settings=settings,
                    record_errors=True,
                    source=spec["source"],
                )
            write_timing(timing_file(out_dir, b, "split"), time.perf_counter() - ts)

    return _build(out_dir, build, "blocks", len(blocks))


def infer_batch(
    zone: str,
    tiles: Sequence[Mapping[str, Any]],
    caches: Mapping[str, str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    preprocess: PreprocessConfig,
    inference: InferenceConfig,
    **kw: Any,
) -> dict[str, Any]:
    """Every tile of a batch, as rule ``infer_tile`` runs one (:func:`towerpipe.jobs.steps.tile_step`).

    Parameters
    ----------
    zone
        The zone.
    tiles
        One mapping per tile: ``block``, ``tile``, ``blocks`` (the blocks whose points the tile
        gathers, its own first) and ``missing`` (block → split cache of the blocks near it that
        could not be split).
    caches
        Block → its split cache, for every block a tile gathers.
    out_dir
        The batch's directory (:data:`towerpipe.io.workdir.BATCH_INFER`): the tiles, DTMs,
        predictions and conductor points of its blocks, in the zone's layout.
    preprocess, inference, kw
        As for :func:`~towerpipe.jobs.steps.tile_step` (``choice``, ``verifier``).
    """

    def build(out_dir: Path) -> None:
        for t in tiles:
            _tile(zone, t, caches, out_dir, preprocess=preprocess, inference=inference, **kw)

    return _build(out_dir, build, "tiles", len(tiles))


def _tile(
    zone: str,
    t: Mapping[str, Any],
    caches: Mapping[str, str | os.PathLike[str]],
    out_dir: Path,
    **kw: Any,
) -> None:
    """One tile of :func:`infer_batch`, and its time."""
    from towerpipe.jobs.steps import tile_step

    b, tile = t["block"], t["tile"]
    ts = time.perf_counter()
    with _naming(b):
        tile_step(
            zone,
            b,
            tile,
            {n: caches[n] for n in t["blocks"]},
            _out(out_dir, workdir.TILE, block=b, tile=tile),
            _out(out_dir, workdir.PRED, block=b, tile=tile),
            dtm_path=_out(out_dir, workdir.DTM, block=b, tile=tile),
            out_wires=_out(out_dir, workdir.WIRES, block=b, tile=tile),
            missing=t.get("missing") or {},
            **kw,
        )
    write_timing(timing_file(out_dir, b, "infer"), time.perf_counter() - ts)


def products_batch(
    zone: str,
    blocks: Sequence[Mapping[str, Any]],
    out_dir: str | os.PathLike[str],
    *,
    towers_cfg: Mapping[str, Any],
    run_cfg: Mapping[str, Any],
    threshold: float,
    limits: Limits,
    registry: Sequence[str] = (),
) -> dict[str, Any]:
    """Every block of a batch: its towers, its classified LAZ and its QA page, as rules
    ``towers_block``, ``merge_block`` and ``qa_block`` make them.

    Parameters
    ----------
    zone
        The zone.
    blocks
        One mapping per block, the arguments of its three jobs: ``block``, ``bounds``,
        ``survey``, ``source_files``, ``preds`` (its tiles' predictions, then its
        neighbours'), ``tiles`` (its tiles, then its neighbours'), ``wires``, ``cache``,
        ``file`` (the input block), ``crs``, ``own_tiles``, ``own_preds``, ``dtms``,
        ``benchmarks`` (stage → benchmark TSVs, for its QA page) and ``block_bounds``.
    out_dir
        The batch's directory (:data:`towerpipe.io.workdir.BATCH_PRODUCTS`).
    towers_cfg, run_cfg, threshold, limits, registry
        As for the per-block jobs (the ``towers`` section, the run's parameters, the point
        threshold, the QA limits, where the zone's tower registry may be).
    """

    def build(out_dir: Path) -> None:
        for spec in blocks:
            with _naming(spec["block"]):
                _block_products(
                    zone,
                    spec,
                    out_dir,
                    towers_cfg=towers_cfg,
                    run_cfg=run_cfg,
                    threshold=threshold,
                    limits=limits,
                    registry=registry,
                )

    return _build(out_dir, build, "blocks", len(blocks))


def _block_products(
    zone: str,
    spec: Mapping[str, Any],
    out_dir: str | os.PathLike[str],
    *,
    towers_cfg: Mapping[str, Any],
    run_cfg: Mapping[str, Any],
    threshold: float,
    limits: Limits,
    registry: Sequence[str],
) -> None:
    """One block of :func:`products_batch`: its towers, then its LAZ and its QA page."""
    from towerpipe.io.blockcache import BlockCache
    from towerpipe.jobs.steps import qa_step, towers_step
    from towerpipe.products.merge import merge_block

    b = spec["block"]
    ts = time.perf_counter()
    gpkg = _out(out_dir, workdir.TOWERS_GPKG, block=b)
    neighbours = _out(out_dir, workdir.TOWERS_NEIGHBOURS, block=b)
    members = _out(out_dir, workdir.TOWER_MEMBERS, block=b)
    towers_step(
        zone,
        b,
        spec["bounds"],
        list(spec["preds"]),
        gpkg,
        towers_cfg=towers_cfg,
        source_files=spec["source_files"],
        run_cfg=run_cfg,
        out_neighbours=neighbours,
        point_threshold=threshold,
        tile_files=list(spec["tiles"]),
        wire_files=list(spec["wires"]),
        out_members=members,
        survey=spec["survey"],
        registry=registry,
        cache_dir=spec["cache"],
    )
    write_timing(timing_file(out_dir, b, "towers"), time.perf_counter() - ts)
    ts = time.perf_counter()
    merge_block(
        spec["file"],
        spec["own_preds"],
        _out(out_dir, workdir.BLOCK_LAZ, block=b),
        threshold=threshold,
        crs=spec["crs"],
        block=b,
        records=BlockCache(spec["cache"]).records_path,
        tower_points=[members],
    )
    write_timing(timing_file(out_dir, b, "merge"), time.perf_counter() - ts)
    # as for a block with jobs of its own: the stages before its QA (the merge: the zone's index)
    benchmarks = {**spec["benchmarks"], "towers": [timing_file(out_dir, b, "towers")]}
    qa_step(
        zone,
        b,
        cache_dir=spec["cache"],
        tile_files=spec["own_tiles"],
        pred_files=spec["own_preds"],
        towers_gpkg=gpkg,
        threshold=threshold,
        limits=limits,
        dtm_files=spec["dtms"],
        benchmarks=benchmarks,
        out_html=_out(out_dir, workdir.QA_HTML, block=b),
        out_json=_out(out_dir, workdir.QA_JSON, block=b),
        neighbours_json=neighbours,
        member_files=[members],
        block_bounds=spec["block_bounds"],
    )
