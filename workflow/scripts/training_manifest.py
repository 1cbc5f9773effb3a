from towerpipe.jobs.smk import run_step
from towerpipe.jobs.training import training_manifest_step

run_step(
    snakemake,
    lambda: training_manifest_step(snakemake.params.zones, snakemake.params.dataset, snakemake.output.manifest),
)
