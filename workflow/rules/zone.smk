# Zone assembly: results/<zone>/ from per-block products (hard links), zone GeoPackage, QA index.


rule assemble_zone:
    input:
        lambda wc: list(zone_products(wc.zone).values()),
    output:
        directory("results/{zone}/"),
    params:
        files=lambda wc: zone_products(wc.zone),
        gpkgs=lambda wc: [f"{WORK}/{wc.zone}/towers/{b}.gpkg" for b in blocks(wc.zone)],
        qa=lambda wc: [f"{WORK}/{wc.zone}/qa/{b}.json" for b in blocks(wc.zone)],
        run=run_params(),
        # the tower registry: updated by each assembly (state kept across runs, not an output)
        registry=lambda wc: registry_file(wc.zone),
    log:
        f"{WORK}/{{zone}}/logs/assemble_zone.log",
    benchmark:
        f"{WORK}/{{zone}}/benchmarks/assemble_zone.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    script:
        "../scripts/assemble_zone.py"
