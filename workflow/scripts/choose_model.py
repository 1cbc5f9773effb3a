from towerpipe.model.choice import write_choice
from towerpipe.jobs.smk import run_step

run_step(snakemake, lambda: write_choice(
    snakemake.params.spec, snakemake.params.caches, snakemake.output.choice,
    zone=snakemake.wildcards.zone, key=snakemake.params.key))
