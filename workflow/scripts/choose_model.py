from towerpipe.jobs.smk import run_step
from towerpipe.model.choice import write_choice

run_step(
    snakemake,
    lambda: write_choice(
        snakemake.params.spec,
        snakemake.params.caches,
        snakemake.output.choice,
        zone=snakemake.wildcards.zone,
        key=snakemake.params.key,
    ),
)
