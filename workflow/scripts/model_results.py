from towerpipe.jobs.smk import run_step
from towerpipe.jobs.training import model_results_step

run_step(snakemake, lambda: model_results_step(snakemake.input.bundle, snakemake.input.ablation, snakemake.output[0]))
