# A zone of small blocks (towerpipe.preprocess.batches): per batch of neighbouring blocks, one job
# for their splits, one for every tile's preprocessing and inference and one for every block's
# towers, classified LAZ and QA page, instead of a job per block, per tile and three per block.
# The jobs call the per-block steps with the per-block rules' arguments (split_batch_args,
# batch_tiles, batch_blocks_args) and write the same files into the batch's directories, in the
# zone's layout (towerpipe.io.workdir).


# The splits come before the plan: their batches are drawn from the blocks' headers
# (split_batches), and a block that cannot be read records why in its cache, as with rule
# split_block. The block files are parameters, as for rule split_block.
rule split_batch:
    output:
        directory(BATCH_SPLIT),
    log:
        log_of("split_batch", "batch"),
    benchmark:
        benchmark_of("split_batch", "batch")
    conda:
        "../envs/towerpipe.yaml"
    # one thread (rule split_block's two decode a large block's LAZ): a batch's blocks are small,
    # and two batches then split side by side
    threads: 1
    resources:
        mem_mb=batch_mem_mb(160, of=split_batches),
        runtime=30,
    params:
        blocks=lambda wc: split_batch_args(wc.zone, wc.batch),
        preprocess=PREP,
    script:
        "../scripts/split_batch.py"


rule infer_batch:
    input:
        caches=lambda wc: cache_inputs(wc.zone, batch_caches(wc.zone, wc.batch)),
        model=lambda wc: model_files(wc.zone),
        # as for the tile jobs: after the zone's model is chosen (a checkpoint)
        choice=lambda wc: ancient(model_choice_file(wc.zone)),
        verifier=verifier_files(),
    output:
        directory(BATCH_INFER),
    log:
        log_of("infer_batch", "batch"),
    benchmark:
        benchmark_of("infer_batch", "batch")
    wildcard_constraints:
        zone=PRODUCT_ZONE,
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=batch_mem_mb(260, base_mb=800),
        runtime=90,
    params:
        tiles=lambda wc: batch_tiles(wc.zone, wc.batch),
        caches=lambda wc: batch_caches(wc.zone, wc.batch),
        preprocess=PREP,
        inference={k: v for k, v in INFER.items() if k != "threshold"},
        verifier=TOWERS["verifier"],
    script:
        "../scripts/infer_batch.py"


rule products_batch:
    input:
        # the batch's predictions, tiles and conductor points and its neighbouring batches'
        infer=lambda wc: batch_infer_inputs(wc.zone, wc.batch),
        caches=lambda wc: cache_inputs(wc.zone, batches(wc.zone)[wc.batch]),
        verifier=verifier_files(),
    output:
        # `snakemake --report` shows each block's QA page, as for rule qa_block
        report(
            directory(BATCH_PRODUCTS),
            patterns=["qa/{block}.html"],
            caption="../report/qa.rst",
            category="QA",
            subcategory="{zone}",
            labels={"zone": "{zone}", "block": "{block}"},
        ),
    log:
        log_of("products_batch", "batch"),
    benchmark:
        benchmark_of("products_batch", "batch")
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=batch_mem_mb(120, base_mb=1000),
        runtime=60,
    params:
        blocks=lambda wc: batch_blocks_args(wc.zone, wc.batch),
        towers=TOWERS,
        threshold=INFER["threshold"],
        run=run_params(),
        qa=config["qa"],
        # read, not an input, as for the towers jobs
        registry=lambda wc: registry_sources(wc.zone),
    script:
        "../scripts/products_batch.py"
