from towerpipe.evaluation.realshape import run_benchmark
from towerpipe.jobs.smk import run_step

run_step(
    snakemake,
    lambda: run_benchmark(
        snakemake.params.loso,
        snakemake.params.zones,
        work=snakemake.config["workdir"],
        inference=snakemake.params.inference,
        towers=snakemake.params.towers,
        out_dir=snakemake.output[0],
        verifiers=snakemake.params.verifiers,
    ),
)
