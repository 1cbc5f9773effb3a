from towerpipe.jobs.smk import run_step
from towerpipe.training.dataset import build_windows

run_step(
    snakemake,
    lambda: build_windows(
        list(snakemake.input.tiles), snakemake.params.dataset, snakemake.output.windows, truth=snakemake.params.truth
    ),
)
