from towerpipe.io.workdir import block_cache
from towerpipe.jobs.smk import run_step
from towerpipe.jobs.steps import qa_step
from towerpipe.products.qa.metrics import Limits

i = snakemake.input
run_step(
    snakemake,
    lambda: qa_step(
        snakemake.wildcards.zone,
        snakemake.wildcards.block,
        cache_dir=block_cache(i.cache, snakemake.wildcards.block),
        tile_files=i.tiles,
        pred_files=i.preds,
        towers_gpkg=i.towers,
        threshold=snakemake.params.threshold,
        limits=Limits.from_config({"qa": snakemake.params.qa, "towers": snakemake.params.towers}),
        dtm_files=i.dtms,
        benchmarks=snakemake.params.benchmarks,
        out_html=snakemake.output.html,
        out_json=snakemake.output.json,
        neighbours_json=i.neighbours,
        member_files=[i.members],
        block_bounds=snakemake.params.block_bounds,
    ),
)
