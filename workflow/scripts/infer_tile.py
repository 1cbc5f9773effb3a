from towerpipe.config import InferenceConfig, PreprocessConfig
from towerpipe.io.workdir import block_cache
from towerpipe.jobs.smk import run_step
from towerpipe.jobs.steps import tile_step

run_step(
    snakemake,
    lambda: tile_step(
        snakemake.wildcards.zone,
        snakemake.wildcards.block,
        snakemake.wildcards.tile,
        {b: block_cache(c, b) for b, c in zip(snakemake.params.blocks, snakemake.input.caches, strict=True)},
        snakemake.output.tile,
        snakemake.output.pred,
        dtm_path=snakemake.output.dtm,
        preprocess=PreprocessConfig.from_config({"preprocess": snakemake.params.preprocess}),
        inference=InferenceConfig.from_config({"inference": snakemake.params.inference}),
        out_wires=snakemake.output.wires,
        missing=snakemake.params.missing,
        choice=snakemake.input.choice,
        verifier=snakemake.params.verifier,
    ),
)
