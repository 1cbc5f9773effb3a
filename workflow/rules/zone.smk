# Zone assembly: results/<zone>/ from per-block products (hard links), zone GeoPackage, QA index.
#
# Snakemake deletes a directory() output before rerunning its rule, which would leave no
# results/<zone>/ while the zone is rebuilt (and only a half-built one after a kill). So the
# assembly's output is a manifest; towerpipe.jobs.zone.zone_step builds the zone in
# work/<zone>/published/ and swaps results/<zone>/ in atomically (never deleting it first).
# zone_results only recreates results/<zone>/ when it is missing (its input is ancient).
rule assemble_zone:
    input:
        lambda wc: planned_products(wc.zone),
    output:
        manifest=PUBLISHED,
    log:
        log_of("assemble_zone"),
    benchmark:
        benchmark_of("assemble_zone")
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        results=RESULTS,
        # the published zone is kept beside its manifest: work/<zone>/published/
        stage=lambda wc, output: os.path.splitext(output.manifest)[0],
        # (where a block's products are: its batch's directory or the zone's, known_batches)
        files=lambda wc: zone_products(wc.zone, known_batches(wc.zone)),
        gpkgs=lambda wc: [
            block_file(wc.zone, b, workdir.TOWERS_GPKG, known=known_batches(wc.zone)) for b in blocks(wc.zone)
        ],
        qa=lambda wc: [block_file(wc.zone, b, workdir.QA_JSON, known=known_batches(wc.zone)) for b in blocks(wc.zone)],
        # the merge runs beside the block's QA page: the zone's index reports its time
        merge_benchmarks=lambda wc: merge_benchmarks(wc.zone, known_batches(wc.zone)),
        sources=lambda wc: {b: i.relpath for b, i in inputs(wc.zone).items()},
        # the zone's files of zero points: listed on the QA index, never run
        empty=lambda wc: empty_blocks(wc.zone),
        run=run_params(),
        block_bounds=lambda wc: bounds(wc.zone),
        # the tower registry: updated by each assembly (state kept across runs, not an output)
        registry=lambda wc: registry_file(wc.zone),
    script:
        "../scripts/assemble_zone.py"


rule zone_results:
    input:
        # a manifest without the zone's plan is removed first (publication)
        lambda wc: ancient(publication(wc.zone)),
    output:
        # `snakemake --report` shows the zone's QA index and its GeoPackage
        report(
            directory(f"{RESULTS}/"),
            patterns=["qa/{page,index}.html", "{name,towers}.gpkg"],
            caption="../report/zone.rst",
            category="Zone",
            subcategory="{zone}",
        ),
    log:
        log_of("zone_results"),
    benchmark:
        benchmark_of("zone_results")
    localrule: True
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        stage=lambda wc, input: os.path.splitext(input[0])[0],
    script:
        "../scripts/zone_results.py"
