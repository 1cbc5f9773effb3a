# The zone's model, then gated window inference per tile, then back into every point of each block.


rule choose_model:
    input:
        caches=lambda wc: [cache_dir(wc.zone, b) for b in blocks(wc.zone)],
    output:
        choice=f"{WORK}/{{zone}}/model.json",
    params:
        spec=lambda wc: model_spec_of(wc.zone)[0],
        key=lambda wc: model_spec_of(wc.zone)[1],
        caches=lambda wc: {b: cache_dir(wc.zone, b) for b in blocks(wc.zone)},
    log:
        f"{WORK}/{{zone}}/logs/choose_model.log",
    benchmark:
        f"{WORK}/{{zone}}/benchmarks/choose_model.tsv"
    conda:
        "../envs/towerpipe.yaml"
    localrule: True
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    script:
        "../scripts/choose_model.py"


rule infer_tile:
    input:
        tile=f"{WORK}/{{zone}}/tiles/{{block}}/{{tile}}.npz",
        model=lambda wc: model_files(wc.zone),
        # after the zone's model is chosen; a rewritten choice alone reruns nothing
        choice=lambda wc: ancient(model_choice_file(wc.zone)),
    output:
        pred=f"{WORK}/{{zone}}/pred/{{block}}/{{tile}}.npz",
    params:
        # the point threshold applies after the windows (towers, merge): changing it
        # does not rerun the inference
        inference={k: v for k, v in INFER.items() if k != "threshold"},
    log:
        f"{WORK}/{{zone}}/logs/infer_tile/{{block}}/{{tile}}.log",
    benchmark:
        f"{WORK}/{{zone}}/benchmarks/infer_tile/{{block}}/{{tile}}.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=lambda wc: mem_mb_for_points(
            block_points(wc.zone, wc.block)
            * min(1.0, ((PREP["tile_size"] + 2 * PREP["buffer"]) ** 2) / 1e6),
            120,
            base_mb=800,
        ),
        runtime=60,
    script:
        "../scripts/infer_tile.py"


rule merge_block:
    input:
        preds=lambda wc: block_preds(wc.zone, wc.block),
        summary=f"{WORK}/{{zone}}/prep/{{block}}.json",
        # the split's copy of the point records: the merge does not decode the LAZ again
        cache=lambda wc: cache_dir(wc.zone, wc.block),
        # the points of the towers reported with points in this block: class 15
        members=f"{WORK}/{{zone}}/towers/{{block}}.points.npz",
    output:
        laz=f"{WORK}/{{zone}}/out/{{block}}.laz",
    params:
        # the file, not an input: the cache (from its split) is, and its fingerprint reruns the split
        block=lambda wc: block_path(wc.zone, wc.block),
        threshold=INFER["threshold"],
        crs=lambda wc: zone_config(wc.zone).get("crs"),
    log:
        f"{WORK}/{{zone}}/logs/merge_block/{{block}}.log",
    benchmark:
        f"{WORK}/{{zone}}/benchmarks/merge_block/{{block}}.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 2
    resources:
        mem_mb=lambda wc: mem_mb_for_points(block_points(wc.zone, wc.block), 24),
        runtime=30,
    script:
        "../scripts/merge_block.py"
