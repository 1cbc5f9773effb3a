from towerpipe.jobs.batch import products_batch
from towerpipe.jobs.smk import run_step
from towerpipe.products.qa.metrics import Limits

p = snakemake.params
run_step(
    snakemake,
    lambda: products_batch(
        snakemake.wildcards.zone,
        p.blocks,
        snakemake.output[0],
        towers_cfg=p.towers,
        run_cfg=p.run,
        threshold=p.threshold,
        limits=Limits.from_config({"qa": p.qa, "towers": p.towers}),
        registry=p.registry,
    ),
)
