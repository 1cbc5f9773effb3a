from towerpipe.ablation import run_ablation
from towerpipe.smk import run_step

run_step(snakemake, lambda: run_ablation(
    list(snakemake.input.tiles), snakemake.output.out,
    config=dict(snakemake.params.train, feature_set=snakemake.params.feature_set)))
