from towerpipe.preprocess.tile import PreprocessConfig, split_block
from towerpipe.jobs.smk import run_step

run_step(snakemake, lambda: split_block(
    snakemake.params.block, snakemake.output.cache, block=snakemake.wildcards.block,
    zone=snakemake.wildcards.zone, crs=snakemake.params.crs, zone_crs=snakemake.params.zone_crs,
    config=PreprocessConfig.from_dict(snakemake.params.preprocess), record_errors=True,
    source=snakemake.params.source))
