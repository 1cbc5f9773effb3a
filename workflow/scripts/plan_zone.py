from towerpipe.io.workdir import block_cache
from towerpipe.jobs.smk import run_step
from towerpipe.preprocess.batches import BatchConfig
from towerpipe.preprocess.tiling import plan_zone_step

run_step(
    snakemake,
    lambda: plan_zone_step(
        {b: block_cache(c, b) for b, c in zip(snakemake.params.blocks, snakemake.input.caches, strict=True)},
        snakemake.output.plan,
        tile_size=snakemake.params.preprocess["tile_size"],
        buffer=snakemake.params.preprocess["buffer"],
        batch=BatchConfig.from_config({"batch": snakemake.params.batch}) if snakemake.params.batch else None,
    ),
)
