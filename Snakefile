# towerpipe: power transmission towers in airborne LiDAR (Carós et al. 2022).
#   snakemake --cores 2 results/<zone>/          one zone, raw blocks in -> products out
#   snakemake --cores 2 results/models/<name>/   train the models on a training zone
from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "config/schema.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/synth.smk"
include: "workflow/rules/preprocess.smk"
include: "workflow/rules/infer.smk"
include: "workflow/rules/products.smk"
include: "workflow/rules/zone.smk"
include: "workflow/rules/train.smk"


rule all:
    default_target: True
    input:
        "results/demo/",


onerror:
    # With --keep-going the other blocks completed: publish them, and the failures, in an
    # explicitly INCOMPLETE zone directory whose QA index names each failed block and why.
    from towerpipe.steps import assemble_incomplete_zone, failures_from_log

    for _zone, _failed in failures_from_log(log, WORK).items():
        if _zone in config["zones"]:
            assemble_incomplete_zone(_zone, f"results/{_zone}", zone_products(_zone), _failed,
                                     run_cfg=run_params(), registry=registry_file(_zone))
            print(f"towerpipe: results/{_zone}/ is INCOMPLETE; failed blocks: {', '.join(sorted(_failed))}")
