from towerpipe.config import PreprocessConfig
from towerpipe.jobs.smk import run_step
from towerpipe.preprocess.split import split_block

run_step(
    snakemake,
    lambda: split_block(
        snakemake.params.block,
        snakemake.output.cache,
        block=snakemake.wildcards.block,
        zone=snakemake.wildcards.zone,
        crs=snakemake.params.crs,
        zone_crs=snakemake.params.zone_crs,
        settings=PreprocessConfig.from_config({"preprocess": snakemake.params.preprocess}),
        record_errors=True,
        source=snakemake.params.source,
    ),
)
