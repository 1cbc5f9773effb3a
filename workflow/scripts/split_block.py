from towerpipe.jobs.smk import run_step
from towerpipe.preprocess.settings import PreprocessConfig
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
        config=PreprocessConfig.from_dict(snakemake.params.preprocess),
        record_errors=True,
        source=snakemake.params.source,
    ),
)
