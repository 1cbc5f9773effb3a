from towerpipe.jobs.smk import run_step
from towerpipe.preprocess.tile import summarize_block

run_step(snakemake, lambda: summarize_block(snakemake.input.cache, snakemake.input.tiles, snakemake.output.summary))
