from towerpipe.smk import run_step
from towerpipe.steps import zone_step

run_step(snakemake, lambda: zone_step(
    snakemake.wildcards.zone, snakemake.output[0], snakemake.params.files,
    tower_gpkgs=snakemake.params.gpkgs, qa_jsons=snakemake.params.qa, run_cfg=snakemake.params.run,
    registry=snakemake.params.registry))
