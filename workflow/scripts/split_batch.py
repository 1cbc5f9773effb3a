from towerpipe.config import PreprocessConfig
from towerpipe.jobs.batch import split_batch
from towerpipe.jobs.smk import run_step

run_step(
    snakemake,
    lambda: split_batch(
        snakemake.wildcards.zone,
        snakemake.params.blocks,
        snakemake.output[0],
        settings=PreprocessConfig.from_config({"preprocess": snakemake.params.preprocess}),
    ),
)
