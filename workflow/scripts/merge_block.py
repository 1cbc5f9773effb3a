from towerpipe.io.blockcache import BlockCache
from towerpipe.io.workdir import block_cache
from towerpipe.jobs.smk import run_step
from towerpipe.products.merge import merge_block

run_step(
    snakemake,
    lambda: merge_block(
        snakemake.params.block,
        snakemake.input.preds,
        snakemake.output.laz,
        threshold=snakemake.params.threshold,
        crs=snakemake.params.crs,
        block=snakemake.wildcards.block,
        records=BlockCache(block_cache(snakemake.input.cache, snakemake.wildcards.block)).records_path,
        tower_points=[snakemake.input.members],
    ),
)
