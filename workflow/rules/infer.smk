# Inference: the zone's model, then each tile's preprocessing and gated window inference
# (paper 3.1-3.3).


# A checkpoint: the tile jobs, which read the choice, are planned once it is made. Made by a rule
# that had to run, the choice hid them: Snakemake judges nothing behind a job that must run, and
# their ancient() input on the choice marks nothing to run, so neither their missing outputs nor
# their changed parameters counted (a new block was split and no more; a changed
# inference.model reran only the choice).
checkpoint choose_model:
    input:
        caches=lambda wc: cache_inputs(wc.zone, blocks(wc.zone)),
        cards=lambda wc: model_cards(wc.zone),
    output:
        choice=MODEL_CHOICE,
    log:
        log_of("choose_model"),
    benchmark:
        benchmark_of("choose_model")
    # right after the splits (it reads only their metadata): every tile job waits on it
    priority: 20
    localrule: True
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        spec=lambda wc: model_spec_of(wc.zone)[0],
        key=lambda wc: model_spec_of(wc.zone)[1],
        caches=lambda wc: {b: cache_dir(wc.zone, b) for b in blocks(wc.zone)},
    script:
        "../scripts/choose_model.py"


# A tile of a zone with products: its preprocessing (as rule preprocess_tile's), the tile written
# for the block's towers and QA jobs, then its inference on the tile in memory: one process and one
# read of the points less than two jobs. Zones that are only prepared (training, the real-shape
# benchmark: PREPARED_ONLY) run rule preprocess_tile instead.
rule infer_tile:
    input:
        caches=tile_caches,
        model=lambda wc: model_files(wc.zone),
        # after the zone's model is chosen (a checkpoint); a rewritten choice alone reruns nothing,
        # a changed model reruns the tile through its model files and parameters
        choice=lambda wc: ancient(model_choice_file(wc.zone)),
        # the shape gate's verifier (inference.shape_gate, towers.verifier)
        verifier=verifier_files(),
    output:
        tile=TILE,
        dtm=DTM,
        pred=PRED,
        # the tile's conductor points (the wire search needs only the tile): the towers job's
        # conductor_points layer
        wires=WIRES,
    log:
        log_of("infer_tile", "tile"),
    benchmark:
        benchmark_of("infer_tile", "tile")
    wildcard_constraints:
        zone=PRODUCT_ZONE,
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        # the preprocessing's peak (PDAL's heights of the tile's points), then the networks
        mem_mb=tile_mem_mb(260, base_mb=800),
        runtime=90,
    params:
        blocks=lambda wc: tile_blocks(wc.zone, wc.block, wc.tile),
        missing=missing_neighbours,
        preprocess=PREP,
        # the point threshold applies after the windows (towers, merge): changing it
        # does not rerun the inference
        inference={k: v for k, v in INFER.items() if k != "threshold"},
        verifier=TOWERS["verifier"],
    script:
        "../scripts/infer_tile.py"
