# Preprocessing (paper 3.1): decode once per block (split), plan the zone's tiles from the
# measured bounds, then ground/DTM/HAG/noise per tile (the QA page sums up the block).


# The block file is a parameter, not an input: its fingerprint (towerpipe.io.inputs) reruns the
# split when its content changes, whatever its mtime, and any file name works (Snakemake reads
# braces in an input path as wildcards).
rule split_block:
    output:
        cache=directory(CACHE),
    log:
        log_of("split_block", "block"),
    benchmark:
        benchmark_of("split_block", "block")
    conda:
        "../envs/towerpipe.yaml"
    threads: 2
    resources:
        mem_mb=lambda wc: mem_mb_for_points(block_points(wc.zone, wc.block), 160),
        runtime=30,
    params:
        block=lambda wc: block_path(wc.zone, wc.block),
        source=lambda wc: describe(block_input(wc.zone, wc.block)),
        crs=lambda wc: zone_config(wc.zone).get("crs"),
        zone_crs=lambda wc: zone_crs(wc.zone),
        preprocess=PREP,
    script:
        "../scripts/split_block.py"


# The zone's tiles, neighbours and batches from the bounds and points the split measured: the
# jobs after the split are planned from the points, never from the headers.
checkpoint plan_zone:
    input:
        caches=lambda wc: cache_inputs(wc.zone, blocks(wc.zone)),
    output:
        plan=f"{ZONE_DIR}/plan.json",
    log:
        log_of("plan_zone"),
    benchmark:
        benchmark_of("plan_zone")
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=lambda wc: 500 + known_block_count(wc.zone) // 10,
        runtime=10,
    params:
        blocks=lambda wc: list(blocks(wc.zone)),
        preprocess=PREP,
        # a zone of small blocks: its batches (rules infer_batch, products_batch); never for a
        # zone that is only prepared (its tiles are read one by one)
        batch=lambda wc: None if wc.zone in PREPARED_ONLY else config["batch"],
    script:
        "../scripts/plan_zone.py"


# The tiles of a zone that is only prepared (PREPARED_ONLY: the training zones, the
# real-shape benchmark's); a zone with products preprocesses each tile in its inference job
# (rule infer_tile), which writes the same tile.
rule preprocess_tile:
    input:
        caches=tile_caches,
    output:
        tile=TILE,
        dtm=DTM,
    log:
        log_of("preprocess_tile", "tile"),
    benchmark:
        benchmark_of("preprocess_tile", "tile")
    wildcard_constraints:
        zone=PREPARED_ZONE,
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=tile_mem_mb(260),
        runtime=30,
    params:
        blocks=lambda wc: tile_blocks(wc.zone, wc.block, wc.tile),
        missing=missing_neighbours,
        preprocess=PREP,
    script:
        "../scripts/preprocess_tile.py"


rule prepared_zone:
    """Every tile of a zone, preprocessed (and, for a zone with products, inferred)."""
    input:
        tiles=lambda wc: tile_files(wc.zone),
    output:
        touch(f"{ZONE_DIR}/prepared.done"),
    log:
        log_of("prepared_zone"),
    benchmark:
        benchmark_of("prepared_zone")
    localrule: True
    threads: 1
    resources:
        mem_mb=100,
        runtime=1,
