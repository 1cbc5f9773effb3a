# Per-block products: the classified LAZ (merge: predictions back into every point) and the
# QA page.


rule merge_block:
    input:
        preds=lambda wc: block_preds(wc.zone, wc.block),
        # the split's copy of the point records: the merge does not decode the LAZ again
        cache=lambda wc: cache_input(wc.zone, wc.block),
        # the points of the towers reported with points in this block: class 15
        members=TOWER_MEMBERS,
    output:
        laz=BLOCK_LAZ,
    log:
        log_of("merge_block", "block"),
    benchmark:
        benchmark_of("merge_block", "block")
    conda:
        "../envs/towerpipe.yaml"
    # one thread: the block's QA page, which does not wait for the merge, runs beside it
    # (two threads cut the merge of a 1 km² block from 5.2 to 3.3 s, but then the QA
    # waits for it on 2 cores)
    threads: 1
    resources:
        mem_mb=lambda wc: mem_mb_for_points(block_points(wc.zone, wc.block), 24),
        runtime=30,
    params:
        # the file, not an input: the cache (from its split) is, and its fingerprint reruns the split
        block=lambda wc: block_path(wc.zone, wc.block),
        threshold=INFER["threshold"],
        crs=lambda wc: zone_config(wc.zone).get("crs"),
    script:
        "../scripts/merge_block.py"


rule qa_block:
    input:
        # the block's preprocessing summary is read from these (metadata only)
        cache=lambda wc: cache_input(wc.zone, wc.block),
        tiles=lambda wc: [tile_file(wc.zone, wc.block, t) for t in tiles(wc.zone, wc.block)],
        dtms=lambda wc: [DTM.format(zone=wc.zone, block=wc.block, tile=t) for t in tiles(wc.zone, wc.block)],
        preds=lambda wc: block_preds(wc.zone, wc.block),
        towers=TOWERS_GPKG,
        neighbours=TOWERS_NEIGHBOURS,
        members=TOWER_MEMBERS,
    output:
        html=report(
            QA_HTML,
            caption="../report/qa.rst",
            category="QA",
            subcategory="{zone}",
            labels={"zone": "{zone}", "block": "{block}"},
        ),
        json=QA_JSON,
    log:
        log_of("qa_block", "block"),
    benchmark:
        benchmark_of("qa_block", "block")
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=lambda wc: mem_mb_for_points(block_points(wc.zone, wc.block), 60),
        runtime=10,
    params:
        benchmarks=lambda wc: block_benchmarks(wc.zone, wc.block),
        threshold=INFER["threshold"],
        # what flags the block or a tower for a look (towerpipe.products.qa.metrics.Limits)
        qa=config["qa"],
        towers={k: TOWERS[k] for k in QA_TOWER_RULES},
        # the edge of the data: a tower reaching it may be cut (a seam tower is not)
        block_bounds=lambda wc: around_header_bounds(wc.zone, wc.block),
    script:
        "../scripts/qa_block.py"
