from towerpipe.merge import merge_block
from towerpipe.smk import run_step

run_step(snakemake, lambda: merge_block(
    snakemake.input.block, snakemake.input.preds, snakemake.output.laz,
    threshold=snakemake.params.threshold, crs=snakemake.params.crs, block=snakemake.wildcards.block))
