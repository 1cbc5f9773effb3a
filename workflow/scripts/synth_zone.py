from towerpipe.jobs.smk import run_step
from towerpipe.synth import generate_zone

run_step(snakemake, lambda: generate_zone(snakemake.output[0], **snakemake.params.synth))
