from towerpipe.synth import generate_zone_from_config
from towerpipe.smk import run_step

run_step(snakemake, lambda: generate_zone_from_config(snakemake.output[0], snakemake.params.synth))
