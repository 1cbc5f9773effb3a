"""Jobs: the workflow's step functions (one call per script), Snakemake glue, ``towerpipe run`` and its lock."""
