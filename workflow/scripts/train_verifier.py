from towerpipe.jobs.smk import run_step
from towerpipe.training.verifier import train_verifier

run_step(
    snakemake,
    lambda: train_verifier(
        list(snakemake.input.tiles),
        snakemake.output.verifier,
        snakemake.params.config,
        truth=snakemake.params.truth,
        threads=snakemake.threads,
    ),
)
