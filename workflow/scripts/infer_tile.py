from towerpipe.config import InferenceConfig
from towerpipe.jobs.smk import run_step
from towerpipe.jobs.steps import infer_step

run_step(
    snakemake,
    lambda: infer_step(
        snakemake.input.tile,
        None,
        snakemake.output.pred,
        InferenceConfig.from_config({"inference": snakemake.params.inference}),
        out_wires=snakemake.output.wires,
        choice=snakemake.input.choice,
        verifier=snakemake.params.verifier,
    ),
)
