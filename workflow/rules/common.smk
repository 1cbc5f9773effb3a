# Helpers shared by the rules: zones, blocks, tiles and neighbours.
# Logic lives in src/towerpipe; this file only maps config and files to paths.
import functools
import os
from pathlib import Path

from snakemake.exceptions import WorkflowError

from towerpipe import tiling
from towerpipe.errors import PdalError, TowerpipeError
from towerpipe.lasio import find_blocks, read_header
from towerpipe.pdal import pdal_version

WORK = config["workdir"]
PREP = config["preprocess"]


wildcard_constraints:
    zone=r"[A-Za-z0-9][A-Za-z0-9_.-]*",
    block=r"[^/]+",
    tile=r"-?\d+_-?\d+",


try:
    PDAL_VERSION = pdal_version()
except PdalError as exc:
    raise WorkflowError(f"towerpipe needs PDAL: {exc}")


def zone_config(zone):
    try:
        return config["zones"][zone]
    except KeyError:
        known = ", ".join(sorted(config["zones"]))
        raise WorkflowError(
            f"zone {zone!r} is not configured (known: {known}); add "
            f"`zones: {{{zone}: {{input: DIR}}}}` to a YAML file and pass it with --configfile"
        )


def zone_input(zone):
    """The zone's input directory; generated first when the zone is synthetic."""
    zc = zone_config(zone)
    path = zc["input"]
    if "synth" in zc:
        if os.path.normpath(path) != os.path.normpath(f"data/{zone}"):
            raise WorkflowError(f"zones.{zone}.input must be data/{zone} for a synthetic zone (got {path})")
        checkpoints.synth_zone.get(zone=zone)
    elif not os.path.isdir(path):
        raise WorkflowError(f"zones.{zone}.input: directory {path!r} does not exist")
    return path


@functools.cache
def _blocks(zone, path):
    blocks = find_blocks(path)
    if not blocks:
        raise WorkflowError(f"zones.{zone}.input: no .las/.laz files under {path!r}")
    return blocks


def blocks(zone):
    """Block name -> file, sorted by name."""
    return _blocks(zone, zone_input(zone))


def block_path(zone, block):
    try:
        return blocks(zone)[block]
    except KeyError:
        raise WorkflowError(f"block {block!r} is not in zone {zone!r}")


@functools.cache
def _headers(zone, path):
    out = {}
    for name, p in _blocks(zone, path).items():
        try:
            out[name] = read_header(p)
        except TowerpipeError:
            out[name] = None  # the block's split_block job reports the error
    return out


def headers(zone):
    return _headers(zone, zone_input(zone))


def zone_crs(zone):
    """The CRS most blocks of a zone have (WKT), or None: a block in another CRS is refused."""
    from collections import Counter

    wkts = [h.crs_wkt for h in headers(zone).values() if h is not None and h.crs_wkt]
    return Counter(wkts).most_common(1)[0][0] if wkts else None


def bounds(zone):
    """Header bounds of every readable block."""
    return {b: h.bounds for b, h in headers(zone).items() if h is not None and h.point_count > 0}


def tiles(zone, block):
    b = bounds(zone).get(block)
    return [] if b is None else tiling.tile_ids(b, PREP["tile_size"])


def tile_blocks(zone, block, tile):
    """Blocks whose points may fall in the tile's core or buffer (the block itself first)."""
    b = bounds(zone)
    others = tiling.blocks_for_tile(b[block], tile, PREP["tile_size"], PREP["buffer"], b)
    return [block] + [b for b in others if b != block]


def block_points(zone, block):
    h = headers(zone).get(block)
    return h.point_count if h is not None else 0


def cache_dir(zone, block):
    return f"{WORK}/{zone}/cache/{block}"


def tile_file(zone, block, tile):
    return f"{WORK}/{zone}/tiles/{block}/{tile}.npz"


def tile_files(zone):
    return [tile_file(zone, b, t) for b in blocks(zone) for t in tiles(zone, b)]


def mem_mb_for_points(points, per_point_bytes, base_mb=400):
    return int(base_mb + points * per_point_bytes / 2**20)


def registry_file(zone):
    """The zone's tower registry (towerpipe.registry): written by the assembly, kept across runs."""
    return f"{WORK}/{zone}/registry.gpkg"


def registry_sources(zone):
    """Where the towers jobs look for the registry: the file, else the published towers.gpkg."""
    return [registry_file(zone), f"results/{zone}/towers.gpkg"]


def zone_products(zone):
    """Relative path in results/<zone>/ -> per-block product."""
    files = {}
    for b in blocks(zone):
        files[f"blocks/{b}.laz"] = f"{WORK}/{zone}/out/{b}.laz"
        files[f"towers/{b}.gpkg"] = f"{WORK}/{zone}/towers/{b}.gpkg"
        files[f"qa/{b}.html"] = f"{WORK}/{zone}/qa/{b}.html"
        files[f"qa/{b}.json"] = f"{WORK}/{zone}/qa/{b}.json"
    return files


INFER = config["inference"]
TOWERS = config["towers"]


def model_dir():
    from towerpipe.steps import resolve_model

    return str(resolve_model(INFER["model"]))


def model_files():
    """The model's files: inputs of every inference job, so a new model reruns the zone."""
    d = model_dir()
    return [f"{d}/classifier.pt", f"{d}/segmenter.pt", f"{d}/model_card.json"]


def pred_file(zone, block, tile):
    return f"{WORK}/{zone}/pred/{block}/{tile}.npz"


def block_preds(zone, block):
    return [pred_file(zone, block, t) for t in tiles(zone, block)]


def block_neighbours(zone, block):
    b = bounds(zone)
    if block not in b:
        return []
    return tiling.neighbours(block, b, PREP["buffer"])


def run_params():
    """Parameters that change the products (recorded in the GeoPackage as a hash)."""
    return {"preprocess": PREP, "inference": INFER, "towers": TOWERS}


def block_benchmarks(zone, block):
    bench = f"{WORK}/{zone}/benchmarks"
    return {
        "split": [f"{bench}/split_block/{block}.tsv"],
        "preprocess": [f"{bench}/preprocess_tile/{block}/{t}.tsv" for t in tiles(zone, block)],
        "inference": [f"{bench}/infer_tile/{block}/{t}.tsv" for t in tiles(zone, block)],
        "merge": [f"{bench}/merge_block/{block}.tsv"],
        "towers": [f"{bench}/towers_block/{block}.tsv"],
    }


TRAIN = config["training"]


def training_tiles():
    """Tile files of every training zone (their preprocessing runs first)."""
    return lambda wc: [p for z in TRAIN["zones"] for p in tile_files(z)]


def model_spec(name):
    try:
        return TRAIN["models"][name]
    except KeyError:
        known = ", ".join(sorted(TRAIN["models"]))
        raise WorkflowError(f"model {name!r} is not in training.models (known: {known})")


def init_bundle_files(name):
    """Files of the bundle a model is warm-started from (``train: {init_from: DIR}``), as inputs."""
    d = model_train_config(name).get("init_from")
    return [os.path.join(d, f) for f in ("classifier.pt", "segmenter.pt", "model_card.json")] if d else []


def model_train_config(name, ablation=False):
    base = dict(TRAIN["ablation_config"] if ablation else TRAIN["train"])
    base.update(model_spec(name).get("train", {}))
    return base
