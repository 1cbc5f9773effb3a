# Per-block products: towers (GeoPackage) and the QA page.


rule towers_block:
    input:
        preds=lambda wc: block_preds(wc.zone, wc.block),
        neighbour_preds=lambda wc: [
            p for n in block_neighbours(wc.zone, wc.block) for p in block_preds(wc.zone, n)
        ],
        summary=f"{WORK}/{{zone}}/prep/{{block}}.json",
        # the points around each tower (this block's and its neighbours' tiles, for the
        # towers across an edge): its conductor support (towers.min_wire_support)
        tiles=lambda wc: [
            tile_file(wc.zone, b, t)
            for b in [wc.block, *block_neighbours(wc.zone, wc.block)]
            for t in tiles(wc.zone, b)
        ],
    output:
        gpkg=f"{WORK}/{{zone}}/towers/{{block}}.gpkg",
        neighbours=f"{WORK}/{{zone}}/towers/{{block}}.neighbours.json",
        members=f"{WORK}/{{zone}}/towers/{{block}}.points.npz",
    params:
        bounds=lambda wc: planned(wc.zone, wc.block)["bounds"],
        # where data exists around the block (a tower's ring outside it: support unknown)
        survey=lambda wc: [planned(wc.zone, b)["bounds"] for b in [wc.block, *block_neighbours(wc.zone, wc.block)]],
        source_files=lambda wc: blocks(wc.zone),
        towers=TOWERS,
        threshold=INFER["threshold"],
        run=run_params(),
        # read, not an input: the assembly writes it after every towers job (no cycle), and
        # a new registry reruns nothing; matched towers keep their ids (towerpipe.towers.registry)
        registry=lambda wc: registry_sources(wc.zone),
    log:
        f"{WORK}/{{zone}}/logs/towers_block/{{block}}.log",
    benchmark:
        f"{WORK}/{{zone}}/benchmarks/towers_block/{{block}}.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        # one tile at a time, with the wire search over its high points (the block's conductor
        # points): 290 MB peak for the demo zone's 0.88 M-point tiles
        mem_mb=lambda wc: mem_mb_for_points(
            block_points(wc.zone, wc.block)
            * min(1.0, ((PREP["tile_size"] + 2 * PREP["buffer"]) ** 2) / 1e6),
            120,
            base_mb=600,
        ),
        runtime=10,
    script:
        "../scripts/towers_block.py"


rule qa_block:
    input:
        summary=f"{WORK}/{{zone}}/prep/{{block}}.json",
        cache=lambda wc: cache_dir(wc.zone, wc.block),
        tiles=lambda wc: [tile_file(wc.zone, wc.block, t) for t in tiles(wc.zone, wc.block)],
        dtms=lambda wc: [f"{WORK}/{wc.zone}/dtm/{wc.block}/{t}.tif" for t in tiles(wc.zone, wc.block)],
        preds=lambda wc: block_preds(wc.zone, wc.block),
        towers=f"{WORK}/{{zone}}/towers/{{block}}.gpkg",
        neighbours=f"{WORK}/{{zone}}/towers/{{block}}.neighbours.json",
        members=f"{WORK}/{{zone}}/towers/{{block}}.points.npz",
        # not read (the QA classifies from the cache as the merge does); it orders the
        # QA after the merge, whose time and memory the page reports
        classified=f"{WORK}/{{zone}}/out/{{block}}.laz",
    output:
        html=report(
            f"{WORK}/{{zone}}/qa/{{block}}.html",
            caption="../report/qa.rst",
            category="QA",
            subcategory="{zone}",
            labels={"zone": "{zone}", "block": "{block}"},
        ),
        json=f"{WORK}/{{zone}}/qa/{{block}}.json",
    params:
        benchmarks=lambda wc: block_benchmarks(wc.zone, wc.block),
        threshold=INFER["threshold"],
        # the edge of the data: a tower reaching it may be cut (a seam tower is not)
        block_bounds=lambda wc: {
            b: bounds(wc.zone).get(b) for b in [wc.block, *block_neighbours(wc.zone, wc.block)]
        },
    log:
        f"{WORK}/{{zone}}/logs/qa_block/{{block}}.log",
    benchmark:
        f"{WORK}/{{zone}}/benchmarks/qa_block/{{block}}.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=lambda wc: mem_mb_for_points(block_points(wc.zone, wc.block), 60),
        runtime=10,
    script:
        "../scripts/qa_block.py"
