import os

from towerpipe.products.merge import merge_block
from towerpipe.io.las import RECORDS_FILE
from towerpipe.jobs.smk import run_step

run_step(snakemake, lambda: merge_block(
    snakemake.params.block, snakemake.input.preds, snakemake.output.laz,
    threshold=snakemake.params.threshold, crs=snakemake.params.crs, block=snakemake.wildcards.block,
    records=os.path.join(snakemake.input.cache, RECORDS_FILE), tower_points=[snakemake.input.members]))
