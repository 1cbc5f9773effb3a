from towerpipe.config import InferenceConfig, PreprocessConfig
from towerpipe.jobs.batch import infer_batch
from towerpipe.jobs.smk import run_step

p = snakemake.params
run_step(
    snakemake,
    lambda: infer_batch(
        snakemake.wildcards.zone,
        p.tiles,
        p.caches,
        snakemake.output[0],
        preprocess=PreprocessConfig.from_config({"preprocess": p.preprocess}),
        inference=InferenceConfig.from_config({"inference": p.inference}),
        choice=snakemake.input.choice,
        verifier=p.verifier,
    ),
)
