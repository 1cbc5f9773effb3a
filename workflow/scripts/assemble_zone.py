from towerpipe.jobs.smk import run_step
from towerpipe.jobs.zone import zone_step

p = snakemake.params
run_step(
    snakemake,
    lambda: zone_step(
        snakemake.wildcards.zone,
        p.results,
        p.files,
        tower_gpkgs=p.gpkgs,
        qa_jsons=p.qa,
        merge_benchmarks=p.merge_benchmarks,
        run_cfg=p.run,
        stage_dir=p.stage,
        manifest=snakemake.output.manifest,
        sources=p.sources,
        block_bounds=p.block_bounds,
        registry=p.registry,
        empty=p.empty,
    ),
)
