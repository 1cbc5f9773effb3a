from towerpipe.preprocess import summarize_block
from towerpipe.smk import run_step

run_step(snakemake, lambda: summarize_block(
    snakemake.input.cache, snakemake.input.tiles, snakemake.output.summary))
