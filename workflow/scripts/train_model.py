from towerpipe.smk import run_step
from towerpipe.train import train_bundle

run_step(snakemake, lambda: train_bundle(
    list(snakemake.input.tiles), snakemake.output.bundle, feature_set=snakemake.params.feature_set,
    config=dict(snakemake.params.train, threads=snakemake.threads)))
