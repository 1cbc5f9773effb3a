from towerpipe.jobs.smk import run_step
from towerpipe.training.ablation import run_ablation

if __name__ == "__main__":  # each ablation row runs in a spawned process that re-imports this file
    run_step(
        snakemake,
        lambda: run_ablation(
            list(snakemake.input.tiles),
            snakemake.output.out,
            config=dict(snakemake.params.train, feature_set=snakemake.params.feature_set),
        ),
    )
