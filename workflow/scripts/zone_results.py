from towerpipe.io.atomic import publish_copy
from towerpipe.jobs.smk import run_step

run_step(snakemake, lambda: publish_copy(snakemake.params.stage, snakemake.output[0]))
