from towerpipe.config import PreprocessConfig
from towerpipe.io.workdir import block_cache
from towerpipe.jobs.smk import run_step
from towerpipe.preprocess.tile import preprocess_tile

run_step(
    snakemake,
    lambda: preprocess_tile(
        snakemake.wildcards.zone,
        snakemake.wildcards.block,
        snakemake.wildcards.tile,
        {b: block_cache(c, b) for b, c in zip(snakemake.params.blocks, snakemake.input.caches, strict=True)},
        snakemake.output.tile,
        dtm_path=snakemake.output.dtm,
        settings=PreprocessConfig.from_config({"preprocess": snakemake.params.preprocess}),
        missing=snakemake.params.missing,
    ),
)
