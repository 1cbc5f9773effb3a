# Towers per block (paper 3.4 and the tower rules): from the block's and its neighbours'
# predictions to the block's towers (GeoPackage), the points of each tower, and the towers
# with points in the block that a neighbour owns.


rule towers_block:
    input:
        preds=lambda wc: block_preds(wc.zone, wc.block),
        neighbour_preds=lambda wc: neighbour_preds(wc.zone, wc.block),
        # the block's split: a block that could not be read fails here, with its recorded error
        cache=lambda wc: cache_input(wc.zone, wc.block),
        # the points around each tower (this block's and its neighbours' tiles, for the
        # towers across an edge) and the conductor points their jobs found: its conductor
        # support (towers.min_wire_support; read beside each tile, towers.coverage.TileContext)
        tiles=lambda wc: around_tiles(wc.zone, wc.block),
        around_wires=lambda wc: around_wires(wc.zone, wc.block),
        # the block's conductor points, found by its infer_tile jobs: layer conductor_points
        wires=lambda wc: block_wires(wc.zone, wc.block),
        # the shape check of each tower (towers.verifier, towers.min_shape_score)
        verifier=verifier_files(),
    output:
        gpkg=TOWERS_GPKG,
        neighbours=TOWERS_NEIGHBOURS,
        members=TOWER_MEMBERS,
    log:
        log_of("towers_block", "block"),
    benchmark:
        benchmark_of("towers_block", "block")
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        # one tile at a time (the conductor support around each tower)
        mem_mb=tile_mem_mb(120, base_mb=600),
        runtime=10,
    params:
        bounds=lambda wc: planned(wc.zone, wc.block)["bounds"],
        # where data exists around the block (a tower's ring outside it: support unknown)
        survey=lambda wc: around_survey(wc.zone, wc.block),
        # the input files of the blocks a tower may touch (the block's and its neighbours')
        source_files=lambda wc: around_sources(wc.zone, wc.block),
        towers=TOWERS,
        threshold=INFER["threshold"],
        run=run_params(),
        # read, not an input: the assembly writes it after every towers job (no cycle), and
        # a new registry reruns nothing; matched towers keep their ids (towerpipe.towers.registry)
        registry=lambda wc: registry_sources(wc.zone),
    script:
        "../scripts/towers_block.py"
