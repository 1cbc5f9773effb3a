from towerpipe.jobs.smk import run_step
from towerpipe.training.train import train_bundle

run_step(
    snakemake,
    lambda: train_bundle(
        snakemake.input.windows,
        snakemake.output.bundle,
        feature_set=snakemake.params.feature_set,
        config=dict(snakemake.params.train, threads=snakemake.threads),
    ),
)
