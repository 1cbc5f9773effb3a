from towerpipe.assemble import assemble_directory
from towerpipe.smk import run_step

run_step(snakemake, lambda: assemble_directory(snakemake.output[0], snakemake.params.files))
