from towerpipe.jobs.smk import run_step
from towerpipe.jobs.steps import infer_step

p = snakemake.params.inference
run_step(
    snakemake,
    lambda: infer_step(
        snakemake.input.tile,
        None,
        snakemake.output.pred,
        window=p["window"],
        stride=p["stride"],
        gate=p["gate"],
        combine=p["combine"],
        batch_size=p["batch_size"],
        min_points=p["min_points"],
        min_height=p["min_height"],
        tta=p["tta"],
        windows=p["windows"],
        choice=snakemake.input.choice,
    ),
)
