# Helpers shared by the rules: zones, blocks, tiles and neighbours, the paths of the
# intermediates, logs and benchmarks, and the jobs' memory.
# Logic lives in src/towerpipe; this file only maps config and files to paths.
import functools
import json
import os
import re
import sys
from pathlib import Path

from snakemake.exceptions import WorkflowError

from towerpipe.products import layout
from towerpipe.products.qa.metrics import Limits
from towerpipe.config import exit_with as config_exit
from towerpipe.errors import PdalError, TowerpipeError
from towerpipe.jobs import runlock
from towerpipe.jobs.batch import timing_file
from towerpipe.io import workdir
from towerpipe.io.inputs import describe, is_empty, no_blocks_message, scan_zone
from towerpipe.preprocess.pdal import pdal_version

WORK = config["workdir"]
PREP = config["preprocess"]

# Patterns (wildcards zone, block, tile) of the per-block and per-tile intermediates, and of
# the logs and benchmarks of the rules: work/<zone>/logs/<rule>[/<block>[/<tile>]].log
ZONE_DIR = f"{WORK}/{{zone}}"
ZONE_NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
#: the published zone (written by zone_results), what users open
RESULTS = "results/{zone}"
# (the layout relative to the zone's directory is towerpipe.io.workdir's)
TILE = f"{ZONE_DIR}/{workdir.TILE}"
PRED = f"{ZONE_DIR}/{workdir.PRED}"
WIRES = f"{ZONE_DIR}/{workdir.WIRES}"
TOWERS_GPKG = f"{ZONE_DIR}/{workdir.TOWERS_GPKG}"
TOWERS_NEIGHBOURS = f"{ZONE_DIR}/{workdir.TOWERS_NEIGHBOURS}"
TOWER_MEMBERS = f"{ZONE_DIR}/{workdir.TOWER_MEMBERS}"
BLOCK_LAZ = f"{ZONE_DIR}/{workdir.BLOCK_LAZ}"
CACHE = f"{ZONE_DIR}/{workdir.CACHE}"
DTM = f"{ZONE_DIR}/{workdir.DTM}"
QA_HTML = f"{ZONE_DIR}/{workdir.QA_HTML}"
QA_JSON = f"{ZONE_DIR}/{workdir.QA_JSON}"
#: a block's products in results/<zone>/ (towerpipe.products.layout) -> where its jobs write them
BLOCK_PRODUCTS = {
    layout.BLOCK_LAZ: workdir.BLOCK_LAZ,
    layout.BLOCK_GPKG: workdir.TOWERS_GPKG,
    layout.QA_PAGE: workdir.QA_HTML,
    layout.QA_JSON: workdir.QA_JSON,
}
# a batch's directories (wildcard batch): the same per-block files, in the zone's layout
BATCH_SPLIT = f"{ZONE_DIR}/{workdir.BATCH_SPLIT}"
BATCH_INFER = f"{ZONE_DIR}/{workdir.BATCH_INFER}"
BATCH_PRODUCTS = f"{ZONE_DIR}/{workdir.BATCH_PRODUCTS}"
# the manifest of the zone's last publication (rule assemble_zone)
PUBLISHED = f"{ZONE_DIR}/published.json"
# the zone's model and why (checkpoint choose_model, towerpipe.model.choice)
MODEL_CHOICE = f"{ZONE_DIR}/model.json"


def log_of(rule, per=""):
    """``log:`` of a rule: per "" (zone), "block", "tile" or "batch"."""
    return _per_job(f"{ZONE_DIR}/{workdir.LOGS}", rule, per) + ".log"


def benchmark_of(rule, per=""):
    """``benchmark:`` of a rule: per "" (zone), "block", "tile" or "batch"."""
    return _per_job(f"{ZONE_DIR}/{workdir.BENCHMARKS}", rule, per) + ".tsv"


def _per_job(base, rule, per):
    """``base/rule``, then ``{block}`` and ``{tile}`` as the rule's jobs are per zone, block or tile
    (``{batch}``: per batch)."""
    wildcards = {"": [], "block": ["{block}"], "tile": ["{block}", "{tile}"], "batch": ["{batch}"]}[per]
    return os.path.join(base, rule, *wildcards)


wildcard_constraints:
    zone=ZONE_NAME,
    # block ids are safe file names (towerpipe.io.inputs), whatever the input files are called
    block=r"[A-Za-z0-9_][A-Za-z0-9_.-]*",
    tile=r"-?\d+_-?\d+",
    # batch ids (towerpipe.preprocess.batches.BATCH_ID)
    batch=r"b-?\d+_-?\d+(?:_\d+)?",
    # model names (training.models, -without-<family>): no dot, so never a file of work/models
    name=r"[A-Za-z0-9][A-Za-z0-9_-]*",
    purpose=r"training|verifier",


try:
    PDAL_VERSION = pdal_version()
except PdalError as exc:
    raise WorkflowError(f"towerpipe needs PDAL: {exc}")


def zone_config(zone):
    try:
        return config["zones"][zone]
    except KeyError:
        known = ", ".join(sorted(config["zones"]))
        config_exit(
            f"zone {zone!r} is not configured (known: {known}); add "
            f"`zones: {{{zone}: {{input: DIR}}}}` to a YAML file and pass it with --configfile"
        )


def executes_jobs():
    """Whether this Snakemake process will run jobs (not a dry run, not a cluster job)."""
    return workflow.is_main_process and workflow.executor_plugin is not None and not workflow.dryrun


#: Zone -> what a checkpoint of it returned once complete (zone_input, plan, model_choice_file).
#: Snakemake's completed checkpoints only grow during a run, so the answer holds; asked for every
#: job's input, ``.get()`` expanded the rule's output each time (600,000 times for 4,000 blocks).
_COMPLETE = {"input": {}, "plan": {}, "choice": {}}


def zone_input(zone):
    """The zone's input directory; generated first when the zone is synthetic.

    A run that will execute jobs (not a dry run, not a cluster job) holds the zone's run
    lock from here to its end: one run per zone, whatever started it.
    """
    if zone in _COMPLETE["input"]:
        return _COMPLETE["input"][zone]
    zc = zone_config(zone)
    path = zc["input"]
    _model_files(zone)  # a model that is not there stops the run here, before any job of the zone
    if executes_jobs():
        try:
            runlock.hold_zone(zone)
        except TowerpipeError as exc:
            # one line, no traceback of this input function; 75 (EX_TEMPFAIL): try again later
            print(exc, file=sys.stderr, flush=True)
            raise SystemExit(75)
    if "synth" in zc:
        if os.path.normpath(path) != os.path.normpath(f"data/{zone}"):
            config_exit(f"zones.{zone}.input must be data/{zone} for a synthetic zone (got {path})")
        checkpoints.synth_zone.get(zone=zone)
    elif not os.path.isdir(path):
        config_exit(f"zones.{zone}.input: directory {path!r} does not exist")
    _COMPLETE["input"][zone] = path
    return path


@functools.cache
def _scan(zone, path):
    found = scan_zone(path, cache=f"{WORK}/{zone}/inputs.json")
    if not found:
        config_exit(no_blocks_message(zone, path))
    return found


@functools.cache
def _inputs(zone, path):
    """The zone's blocks: its files but those that hold zero points (listed on the QA index, never run)."""
    found = {b: i for b, i in _scan(zone, path).items() if not is_empty(i)}
    if not found:
        config_exit(f"zones.{zone}.input: every .las/.laz file under {path!r} holds zero points")
    return found


def empty_blocks(zone):
    """Block id -> original file of the zone's files that hold zero points (the QA index lists them)."""
    return {b: i.relpath for b, i in _scan(zone, zone_input(zone)).items() if is_empty(i)}


def inputs(zone):
    """Block id -> towerpipe.io.inputs.BlockInput (file, original name, fingerprint), sorted by id."""
    return _inputs(zone, zone_input(zone))


def blocks(zone):
    """Block id -> file, sorted by id."""
    return _zone_tables(zone, zone_input(zone))["blocks"]


def known_block_count(zone):
    """The zone's number of blocks when this run knows its input, asking no checkpoint; else 0.

    For a resource: Snakemake 9.27 fails a dry run (``'int' object has no attribute
    'constrain'``) whose resource function waits on a checkpoint not run yet, e.g. the
    plan of a synthetic training zone not generated yet.
    """
    path = _COMPLETE["input"].get(zone)
    return 0 if path is None else len(_zone_tables(zone, path)["blocks"])


def bounds(zone):
    """Header bounds of every block with points (the QA index's map places failed blocks with them)."""
    return _zone_tables(zone, zone_input(zone))["bounds"]


@functools.cache
def _zone_tables(zone, path):
    """The zone-wide tables the rules' functions look up once per job: built once per run
    (built per call, a zone of 4,000 blocks took minutes to plan)."""
    from collections import Counter

    found = _inputs(zone, path)
    wkts = [i.header["crs_wkt"] for i in found.values() if i.header and i.header["crs_wkt"]]
    return {
        "blocks": {b: i.path for b, i in found.items()},
        "bounds": {b: i.header.get("bounds") for b, i in found.items() if i.header and i.header.get("point_count")},
        "crs": Counter(wkts).most_common(1)[0][0] if wkts else None,
    }


def block_input(zone, block):
    try:
        return inputs(zone)[block]
    except KeyError:
        raise WorkflowError(f"block {block!r} is not in zone {zone!r}")


def block_path(zone, block):
    return block_input(zone, block).path


def zone_crs(zone):
    """The CRS most blocks of a zone have (WKT), or None: a block in another CRS is refused."""
    return _zone_tables(zone, zone_input(zone))["crs"]


def plan_file(zone):
    return f"{WORK}/{zone}/plan.json"


@functools.cache
def _read_plan(path, mtime_ns):
    """The plan file's content, read once per version of the file."""
    with open(path) as fh:
        return json.load(fh)


def plan(zone):
    """The zone's tiles and neighbours, from the points the split measured (checkpoint plan_zone).

    Nothing in the job graph comes from a block's header: until every block is split,
    the jobs after the split are not known (a dry run lists the splits and the plan).
    """
    return _plan_doc(zone)["blocks"]


def _plan_doc(zone):
    path = _COMPLETE["plan"].get(zone)
    if path is None:
        # the zone's input first: Snakemake 9.27 runs a checkpoint that another rule's input asks
        # for with its own input unresolved when that waits on a checkpoint too (a synthetic zone's
        # input): the plan of a zone whose split was cut short then ran before the missing splits
        zone_input(zone)
        path = _COMPLETE["plan"][zone] = checkpoints.plan_zone.get(zone=zone).output[0]
    return _read_plan(path, os.stat(path).st_mtime_ns)


def plan_or_none(zone):
    """The zone's plan when it exists (no checkpoint: for resources and the error handler)."""
    path = plan_file(zone)
    return _read_plan(path, os.stat(path).st_mtime_ns)["blocks"] if os.path.exists(path) else None


def planned(zone, block):
    return plan(zone).get(block) or {
        "tiles": [],
        "neighbours": [],
        "tile_blocks": {},
        "points": 0,
        "missing_neighbours": [],
        "batch": None,
    }


def batches(zone):
    """Batch id -> its blocks (towerpipe.preprocess.batches); empty for a zone not batched, and
    for one whose model cannot run on some block: each block then has jobs of its own, and that
    block fails alone at its towers job (a batch fails with any of its blocks)."""
    return _batch_index(zone)[0]


def batch_of(zone, block, known=None):
    """The block's batch, or None (a job per tile and per block); ``known``: an index from
    known_batches (a rule's parameters, the error handler), else the checkpoints are asked."""
    return (known or _batch_index(zone))[1].get(block)


def _batch_index(zone):
    plan(zone)  # the checkpoint, once
    path = _COMPLETE["plan"][zone]
    mtime = os.stat(path).st_mtime_ns
    if not _read_plan(path, mtime).get("batches"):  # no choice asked: a zone only prepared has none
        return _NO_BATCHES
    choice = model_choice_file(zone)
    return _batch_index_of(path, mtime, choice, os.stat(choice).st_mtime_ns)


def known_batches(zone):
    """The zone's batch index from the files its checkpoints wrote, asking no checkpoint: for a
    rule's parameters (a parameter may only ask the checkpoint its rule's input asked; the job
    is planned again once the checkpoints are made) and for the error handler."""
    path, choice = plan_file(zone), MODEL_CHOICE.format(zone=zone)
    if not (os.path.exists(path) and os.path.exists(choice)):
        return _NO_BATCHES
    return _batch_index_of(path, os.stat(path).st_mtime_ns, choice, os.stat(choice).st_mtime_ns)


_NO_BATCHES = ({}, {})


@functools.cache
def _batch_index_of(plan_path, plan_mtime_ns, choice_path, choice_mtime_ns):
    """(batches, block -> batch) of a plan and a model choice, built once per version of each."""
    planned_batches = _read_plan(plan_path, plan_mtime_ns).get("batches") or {}
    with open(choice_path) as fh:
        if json.load(fh).get("incompatible_blocks"):
            return _NO_BATCHES
    return planned_batches, {b: i for i, bs in planned_batches.items() for b in bs}


def block_root(zone, block, stage, known=None):
    """Where a block's files of ``stage`` ("infer": tiles, DTMs, predictions, conductor points;
    "products": towers, LAZ, QA) are: its batch's directory, or the zone's."""
    batch = batch_of(zone, block, known)
    if batch is None:
        return ZONE_DIR.format(zone=zone)
    return (BATCH_INFER if stage == "infer" else BATCH_PRODUCTS).format(zone=zone, batch=batch)


def block_file(zone, block, pattern, tile=None, known=None):
    """A per-block file (a towerpipe.io.workdir pattern) where the block's jobs or batch write it."""
    stage = "infer" if pattern in (workdir.TILE, workdir.DTM, workdir.PRED, workdir.WIRES) else "products"
    return f"{block_root(zone, block, stage, known)}/{pattern.format(block=block, tile=tile)}"


def tiles(zone, block):
    return planned(zone, block)["tiles"]


def tile_blocks(zone, block, tile):
    """Blocks whose points may fall in the tile's core or buffer (the block itself first)."""
    return planned(zone, block)["tile_blocks"][tile]


def tile_caches(wc):
    """What makes the caches of the blocks whose points a tile gathers (its block's and its
    neighbours'), one per block of tile_blocks."""
    return cache_inputs(wc.zone, tile_blocks(wc.zone, wc.block, wc.tile))


def missing_neighbours(wc):
    """The blocks near a tile that could not be split (named in the tile's warnings)."""
    return missing_caches(wc.zone, wc.block)


def missing_caches(zone, block):
    """Block -> cache of the blocks near the block's tiles that could not be split."""
    return {b: cache_dir(zone, b) for b in planned(zone, block)["missing_neighbours"]}


def block_points(zone, block):
    """Points of a block for sizing resources: measured once split, else bounded by the file size."""
    n = ((plan_or_none(zone) or {}).get(block) or {}).get("points")
    return n or block_input(zone, block).points_estimate


def cache_dir(zone, block):
    """The block's split cache: in its split batch's directory, or the zone's."""
    batch = split_batch_of(zone, block)
    if batch is None:
        return CACHE.format(zone=zone, block=block)
    return f"{BATCH_SPLIT.format(zone=zone, batch=batch)}/{workdir.CACHE.format(block=block)}"


def cache_input(zone, block):
    """What makes the block's split cache, as a job's input: its split batch's directory (rule
    split_batch), or the cache (rule split_block); the job finds the cache in it with
    towerpipe.io.workdir.block_cache."""
    batch = split_batch_of(zone, block)
    return CACHE.format(zone=zone, block=block) if batch is None else BATCH_SPLIT.format(zone=zone, batch=batch)


def cache_inputs(zone, blocks_):
    """cache_input of each block, in order (a split batch's directory once per block of it)."""
    return [cache_input(zone, b) for b in blocks_]


def split_batches(zone):
    """Batch id -> the blocks one split job decodes (towerpipe.preprocess.batches.split_batches):
    from the blocks' headers, since the split comes before the plan."""
    return _split_index(zone, zone_input(zone))[0]


def known_split_batches(zone):
    """The zone's split batches when this run knows its input, asking no checkpoint (for the
    error handler); else empty."""
    path = _COMPLETE["input"].get(zone)
    return {} if path is None else _split_index(zone, path)[0]


def split_batch_of(zone, block):
    """The block's split batch, or None (a split job of its own)."""
    return _split_index(zone, zone_input(zone))[1].get(block)


@functools.cache
def _split_index(zone, path):
    from towerpipe.preprocess.batches import BatchConfig
    from towerpipe.preprocess.batches import split_batches as of_headers

    found = _inputs(zone, path)
    grouped = of_headers({b: i.header for b, i in found.items()}, BatchConfig.from_config({"batch": config["batch"]}))
    return grouped, {b: i for i, bs in grouped.items() for b in bs}


def split_batch_args(zone, batch):
    """The arguments of each block of a split batch (towerpipe.jobs.batch.split_batch), as rule
    split_block's."""
    return [
        {
            "block": b,
            "file": block_path(zone, b),
            "source": describe(block_input(zone, b)),
            "crs": zone_config(zone).get("crs"),
            "zone_crs": zone_crs(zone),
        }
        for b in split_batches(zone)[batch]
    ]


def tile_file(zone, block, tile):
    return block_file(zone, block, workdir.TILE, tile)


def tile_files(zone):
    """What makes every tile of the zone: the tile files, or the directories of its batches."""
    if zone_batches := batches(zone):
        return [BATCH_INFER.format(zone=zone, batch=i) for i in zone_batches]
    return [tile_file(zone, b, t) for b in blocks(zone) for t in tiles(zone, b)]


def mem_mb_for_points(points, per_point_bytes, base_mb=400):
    return int(base_mb + points * per_point_bytes / 2**20)


def tile_mem_mb(per_point_bytes, base_mb=400):
    """``resources: mem_mb`` of a per-tile job: the block's points in a tile and its buffer."""

    def mem_mb(wc):
        share = min(1.0, ((PREP["tile_size"] + 2 * PREP["buffer"]) ** 2) / 1e6)
        return mem_mb_for_points(block_points(wc.zone, wc.block) * share, per_point_bytes, base_mb=base_mb)

    return mem_mb


def registry_file(zone):
    """The zone's tower registry (towerpipe.towers.registry): written by the assembly, kept across runs."""
    return f"{WORK}/{zone}/registry.gpkg"


def registry_sources(zone):
    """Where the towers jobs look for the registry: the file, else the published towers.gpkg."""
    return [registry_file(zone), f"{RESULTS.format(zone=zone)}/towers.gpkg"]


def zone_products(zone, known=None):
    """Relative path in results/<zone>/ -> per-block product (in its batch's directory for a
    batched block); ``known`` as for batch_of."""
    if zone in PREPARED_ONLY:
        raise WorkflowError(
            f"zone {zone!r} is one the models train on or the real-shape benchmark reads (training.zones, "
            "training.verifier_zones, realshape_*): its tiles are only preprocessed, it has no products; "
            "give its input another zone name to run it as a zone"
        )
    files = {}
    for b in blocks(zone):
        for product, work_file in BLOCK_PRODUCTS.items():
            files[layout.block_product(product, b)] = block_file(zone, b, work_file, known=known)
    return files


def planned_products(zone):
    """The zone's per-block products, once its plan exists: until then the job graph holds
    the splits and the plan only, so a dry run of a new zone of thousands of blocks stays small.
    The blocks come first: a synthetic zone's generation is the checkpoint waited for before
    the plan (the rule's parameters need the blocks)."""
    zone_blocks = blocks(zone)
    plan(zone)
    # a batched block's products are files of its batch's directory: the batch is the input
    products = [f for b in zone_blocks if batch_of(zone, b) is None for f in block_products(zone, b)]
    products += [BATCH_PRODUCTS.format(zone=zone, batch=i) for i in batches(zone)]
    # the tile jobs read the model choice, a checkpoint too: Snakemake judges again only the jobs
    # that ask a checkpoint themselves, so the assembly asks it for them
    model_choice_file(zone)
    return products


@functools.cache
def publication(zone):
    """The zone's publication manifest (input of zone_results). Once per run, first, a
    publication without the zone's plan is set aside (towerpipe.jobs.zone.set_aside_unplanned)."""
    from towerpipe.jobs.zone import set_aside_unplanned

    manifest = PUBLISHED.format(zone=zone)
    done = set_aside_unplanned(
        plan_file(zone), manifest, RESULTS.format(zone=zone), f"{WORK}/{zone}/incomplete", dry_run=not executes_jobs()
    )
    if done:
        print(f"towerpipe: zone {zone}: {done}")
    return manifest


INFER = config["inference"]
TOWERS = config["towers"]
#: the tower rules the QA pages flag against (towerpipe.products.qa.metrics.Limits)
QA_TOWER_RULES = tuple(Limits.FROM_TOWERS.values())


def model_spec_of(zone):
    """``(spec, config key)`` of a zone's model: its own ``model:`` key, else ``inference.model``."""
    own = zone_config(zone).get("model")
    return (own, f"zones.{zone}.model") if own else (INFER["model"], "inference.model")


def model_choice_file(zone):
    """The zone's model choice (checkpoint choose_model), remembered once made."""
    path = _COMPLETE["choice"].get(zone)
    if path is None:
        path = _COMPLETE["choice"][zone] = checkpoints.choose_model.get(zone=zone).output.choice
    return path


def model_files(zone):
    """The files of the models the zone may run: inputs of its inference jobs, so a new model
    reruns the zone. Known without the choice (``auto``: every shipped model; else the one
    named), so they never wait on a checkpoint; the job reads its model from the choice."""
    return list(_model_files(zone))


def model_cards(zone):
    """The cards of the models the zone may run: inputs of its choice, which reads their real-shape
    scores, so a card stamped anew (``towerpipe realshape-stamp``) makes the choice again."""
    from towerpipe.model.cards import CARD_FILE

    return [f for f in _model_files(zone) if os.path.basename(f) == CARD_FILE]


@functools.cache
def _model_files(zone):
    from towerpipe.model.choice import AUTO, resolve_model
    from towerpipe.model.cards import BUNDLE_FILES, MODEL_RELEASES, default_model_path

    spec, key = model_spec_of(zone)
    dirs = [default_model_path(fs) for fs in MODEL_RELEASES] if spec == AUTO else [resolve_model(spec)]
    for d in dirs:
        # a model this workflow trains may come in the same run; any other must be there now
        where, name = os.path.split(os.path.normpath(d))
        trained_here = os.path.normpath(where) in _TRAINED_MODEL_DIRS and name.partition(LOSO)[0] in TRAIN["models"]
        if not os.path.isdir(d) and not trained_here:
            config_exit(
                f"{key}: no model at {str(d)!r}; name `auto`, a shipped feature set "
                f"({', '.join(sorted(MODEL_RELEASES))}), the directory of a trained model, or "
                f"results/models/<name> of a model in training.models"
            )
    return [f"{d}/{f}" for d in dirs for f in BUNDLE_FILES]


#: Where this workflow's training rules put the models they train (rules train_model, model_results).
TRAINED_MODELS, PUBLISHED_MODELS = f"{WORK}/models", "results/models"
_TRAINED_MODEL_DIRS = {os.path.normpath(TRAINED_MODELS), os.path.normpath(PUBLISHED_MODELS)}


def verifier_files():
    """The shape verifier's file (``towers.verifier``): an input of the towers jobs, so a new
    verifier reruns them; none with ``verifier: none``."""
    from towerpipe.towers.shape import VERIFIER_FILE, resolve_verifier

    path = resolve_verifier(TOWERS["verifier"])
    return [] if path is None else [str(path / VERIFIER_FILE)]


def block_products(zone, block):
    """The block's four products in the work directory (of a block with jobs of its own)."""
    return [f"{ZONE_DIR}/{w}".format(zone=zone, block=block) for w in BLOCK_PRODUCTS.values()]


def pred_file(zone, block, tile):
    return block_file(zone, block, workdir.PRED, tile)


def block_preds(zone, block):
    return [pred_file(zone, block, t) for t in tiles(zone, block)]


def block_wires(zone, block):
    return [block_file(zone, block, workdir.WIRES, t) for t in tiles(zone, block)]


def block_neighbours(zone, block):
    return planned(zone, block)["neighbours"]


# What the towers job of a block reads of the blocks around it (rule towers_block, and
# products_batch for each block of a batch): the block first, then its neighbours.
def around(zone, block):
    return [block, *block_neighbours(zone, block)]


def neighbour_preds(zone, block):
    return [p for n in block_neighbours(zone, block) for p in block_preds(zone, n)]


def around_tiles(zone, block):
    """The tiles around each tower (its conductor support, towers.min_wire_support)."""
    return [tile_file(zone, b, t) for b in around(zone, block) for t in tiles(zone, b)]


def around_wires(zone, block):
    """The conductor points found by the tile jobs around each tower (its conductor support)."""
    return [block_file(zone, b, workdir.WIRES, t) for b in around(zone, block) for t in tiles(zone, b)]


def around_survey(zone, block):
    """Where data exists around the block (a tower's ring outside it: support unknown)."""
    return [planned(zone, b)["bounds"] for b in around(zone, block)]


def around_sources(zone, block):
    """The input files of the blocks a tower may touch."""
    return {b: block_path(zone, b) for b in around(zone, block)}


def around_header_bounds(zone, block):
    """The header bounds of the block and its neighbours: the edge of the data (its QA page)."""
    return {b: bounds(zone).get(b) for b in around(zone, block)}


def run_params():
    """Parameters that change the products (recorded in the GeoPackage as a hash)."""
    return {"preprocess": PREP, "inference": INFER, "towers": TOWERS}


def block_benchmarks(zone, block):
    """The benchmark files of the block's jobs that run before its QA page (which reports
    their time and memory); the merge runs beside the QA (merge_benchmarks)."""

    def of(rule, per):
        return [benchmark_of(rule, per).format(zone=zone, block=block, tile=t) for t in tiles(zone, block)]

    split_batch = split_batch_of(zone, block)
    if split_batch is None:
        split = [benchmark_of("split_block", "block").format(zone=zone, block=block)]
    else:  # the block's time in its split batch
        split = [timing_file(BATCH_SPLIT.format(zone=zone, batch=split_batch), block, "split")]
    batch = batch_of(zone, block)
    if batch is not None:  # the block's time in its batch (products_batch adds its towers')
        infer_dir = BATCH_INFER.format(zone=zone, batch=batch)
        return {"split": split, "preprocess + inference": [timing_file(infer_dir, block, "infer")]}
    return {
        "split": split,
        # a tile's preprocessing and inference are one job (rule infer_tile)
        "preprocess + inference": of("infer_tile", "tile"),
        "towers": [benchmark_of("towers_block", "block").format(zone=zone, block=block)],
    }


def merge_benchmarks(zone, known=None):
    """Block → benchmark file of its merge (the zone's QA index reports its time and memory);
    ``known`` as for batch_of."""
    out = {}
    for b in blocks(zone):
        batch = batch_of(zone, b, known)
        if batch is None:
            out[b] = benchmark_of("merge_block", "block").format(zone=zone, block=b)
        else:
            out[b] = timing_file(BATCH_PRODUCTS.format(zone=zone, batch=batch), b, "merge")
    return out


def batch_tiles(zone, batch):
    """The arguments of each tile of a batch (towerpipe.jobs.batch.infer_batch), as rule
    infer_tile's: its block, the blocks whose points it gathers, the missing neighbours."""
    out = []
    for b in batches(zone)[batch]:
        missing = missing_caches(zone, b)
        for t in tiles(zone, b):
            out.append({"block": b, "tile": t, "blocks": tile_blocks(zone, b, t), "missing": missing})
    return out


def batch_caches(zone, batch):
    """Block -> split cache of every block a batch's tiles gather."""
    gathered = sorted({n for t in batch_tiles(zone, batch) for n in t["blocks"]})
    return {n: cache_dir(zone, n) for n in gathered}


def batch_infer_inputs(zone, batch):
    """The inference directories the products of a batch read: its own and its neighbours'."""
    from towerpipe.preprocess.batches import batch_neighbours

    near = batch_neighbours(batches(zone)[batch], plan(zone))
    return [BATCH_INFER.format(zone=zone, batch=i) for i in [batch, *near]]


def batch_blocks_args(zone, batch):
    """The arguments of each block of a batch (towerpipe.jobs.batch.products_batch), as rules
    towers_block, merge_block and qa_block give them."""
    out = []
    for b in batches(zone)[batch]:
        out.append(
            {
                "block": b,
                "bounds": planned(zone, b)["bounds"],
                "survey": around_survey(zone, b),
                "source_files": around_sources(zone, b),
                "preds": block_preds(zone, b) + neighbour_preds(zone, b),
                "tiles": around_tiles(zone, b),
                "wires": block_wires(zone, b),
                "cache": cache_dir(zone, b),
                "file": block_path(zone, b),
                "crs": zone_config(zone).get("crs"),
                "own_tiles": [tile_file(zone, b, t) for t in tiles(zone, b)],
                "own_preds": block_preds(zone, b),
                "dtms": [block_file(zone, b, workdir.DTM, t) for t in tiles(zone, b)],
                "benchmarks": block_benchmarks(zone, b),
                "block_bounds": around_header_bounds(zone, b),
            }
        )
    return out


def batch_mem_mb(per_point_bytes, base_mb=400, of=None):
    """``resources: mem_mb`` of a batch job: its largest block's (the blocks run one after another);
    ``of``: zone -> its batches (default batches; split_batches for the splits)."""

    def mem_mb(wc):
        members = (of or batches)(wc.zone)[wc.batch]
        return max(mem_mb_for_points(block_points(wc.zone, b), per_point_bytes, base_mb) for b in members)

    return mem_mb


TRAIN = config["training"]
#: ``<model>-without-<family>``: the model's recipe trained without one real tower family
#: (the leave-one-source-out benchmark, towerpipe.evaluation.realshape)
LOSO = "-without-"


#: the zones and window settings of the networks' training and of the verifier's (written by
#: training_manifest, {purpose}: training or verifier); a change reruns what reads it
ZONES_MANIFEST = f"{WORK}/models/{{purpose}}_zones.json"
TRAINING_MANIFEST = ZONES_MANIFEST.format(purpose="training")
VERIFIER_MANIFEST = ZONES_MANIFEST.format(purpose="verifier")


def purpose_zones(purpose):
    """The zones the networks train on (``training``), or the verifier (``verifier``: those and
    ``training.verifier_zones``)."""
    if purpose == "training":
        return list(TRAIN["zones"])
    if purpose == "verifier":
        return [*TRAIN["zones"], *(z for z in TRAIN["verifier_zones"] if z not in TRAIN["zones"])]
    raise WorkflowError(f"{ZONES_MANIFEST.format(purpose=purpose)}: no such manifest (training or verifier)")


def training_tiles(purpose="training"):
    """Tile files of every zone of ``purpose`` (their preprocessing runs first)."""
    return lambda wc: [p for z in purpose_zones(purpose) for p in tile_files(z)]


def training_truth(purpose="training"):
    """Zone -> tower truth of the generated zones of ``purpose`` (tower families of the windows)."""
    return {z: f"data/{z}/towers_truth.gpkg" for z in purpose_zones(purpose) if "synth" in zone_config(z)}


def model_spec(name):
    base, _, family = name.partition(LOSO)
    try:
        spec = dict(TRAIN["models"][base])
    except KeyError:
        known = ", ".join(sorted(TRAIN["models"]))
        raise WorkflowError(
            f"model {base!r} is not in training.models (known: {known}; {LOSO}<family> leaves a real tower "
            "family out)"
        )
    if family:
        spec["train"] = {**spec.get("train", {}), "exclude_families": [family]}
    return spec


def init_bundle_files(name):
    """Files of the bundle a model is warm-started from (``train: {init_from: DIR}``), as inputs."""
    from towerpipe.model.cards import BUNDLE_FILES

    d = model_train_config(name).get("init_from")
    return [os.path.join(d, f) for f in BUNDLE_FILES] if d else []


def model_train_config(name, ablation=False):
    base = dict(TRAIN["ablation_config"] if ablation else TRAIN["train"])
    own = dict(model_spec(name).get("train", {}))
    for net in ("classifier", "segmenter"):  # per-network overrides merge, not replace
        if net in own:
            own[net] = {**base.get(net, {}), **own[net]}
    base.update(own)
    return base


def realshape_zones():
    """The zones of the real-shape benchmark (towerpipe.evaluation.realshape), of the variants judged."""
    variants = TRAIN["benchmark_variants"]
    return [
        z
        for z in config["zones"]
        if z.startswith("realshape_") and (not variants or any(z.endswith(f"_{v}") for v in variants))
    ]


def verifier_name():
    from towerpipe.towers.shape import VERIFIER_RELEASE

    return f"towerpipe-verifier-v{VERIFIER_RELEASE}"


def verifier_train_config(name):
    """The shape verifier's recipe (``training.verifier``), without the family its name leaves out."""
    base, _, family = name.partition(LOSO)
    if base != verifier_name():
        raise WorkflowError(f"verifier {name!r}: this towerpipe trains {verifier_name()}[{LOSO}<family>]")
    return {**TRAIN.get("verifier", {}), "exclude_families": [family] if family else []}


def loso_verifiers():
    """Real family -> the shape verifier trained without it (the real-shape benchmark's)."""
    from towerpipe.synth.real import FAMILIES

    return {f: f"{WORK}/verifiers/{verifier_name()}{LOSO}{f}" for f in FAMILIES}


def loso_models():
    """Recipe (feature set) -> real family -> the recipe's model trained without that family."""
    from towerpipe.synth.real import FAMILIES

    judged = TRAIN["benchmark"] or list(TRAIN["models"])
    unknown = sorted(set(judged) - set(TRAIN["models"]))
    if unknown:
        raise WorkflowError(f"training.benchmark: {', '.join(unknown)} not in training.models")
    return {
        TRAIN["models"][name]["feature_set"]: {f: f"{WORK}/models/{name}{LOSO}{f}" for f in FAMILIES} for name in judged
    }


#: The zones whose tiles are only preprocessed, by preprocess_tile jobs: those the networks and the
#: shape verifier train on and those of the real-shape benchmark, which read tiles and never
#: products. Every other zone's tiles are preprocessed and inferred in one job (rule infer_tile).
PREPARED_ONLY = frozenset({*purpose_zones("verifier"), *realshape_zones()} & set(config["zones"]))
_PREPARED_RE = "|".join(re.escape(z) for z in sorted(PREPARED_ONLY))
#: the zone wildcard of rule preprocess_tile (a prepared-only zone) and of rule infer_tile (any
#: other; the name is followed by the "/" of its folder in every path of the two rules)
PREPARED_ZONE = f"(?:{_PREPARED_RE})" if PREPARED_ONLY else "(?!)"
PRODUCT_ZONE = (f"(?!(?:{_PREPARED_RE})/)" if PREPARED_ONLY else "") + ZONE_NAME
