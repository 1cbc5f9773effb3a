from towerpipe.assemble import publish_copy
from towerpipe.smk import run_step

run_step(snakemake, lambda: publish_copy(snakemake.params.stage, snakemake.output[0]))
