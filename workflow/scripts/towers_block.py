from towerpipe.io.workdir import block_cache
from towerpipe.jobs.smk import run_step
from towerpipe.jobs.steps import towers_step

run_step(
    snakemake,
    lambda: towers_step(
        snakemake.wildcards.zone,
        snakemake.wildcards.block,
        snakemake.params.bounds,
        list(snakemake.input.preds) + list(snakemake.input.neighbour_preds),
        snakemake.output.gpkg,
        towers_cfg=snakemake.params.towers,
        source_files=snakemake.params.source_files,
        run_cfg=snakemake.params.run,
        out_neighbours=snakemake.output.neighbours,
        point_threshold=snakemake.params.threshold,
        tile_files=list(snakemake.input.tiles),
        wire_files=list(snakemake.input.wires),
        out_members=snakemake.output.members,
        survey=snakemake.params.survey,
        registry=snakemake.params.registry,
        cache_dir=block_cache(snakemake.input.cache, snakemake.wildcards.block),
    ),
)
