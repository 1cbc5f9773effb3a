# towerpipe: power transmission towers in airborne LiDAR (Carós et al. 2022).
#   snakemake --cores 2 results/<zone>/          one zone, raw blocks in -> products out
#   snakemake --cores 2 results/models/<name>/   train the models on a training zone
from snakemake.utils import min_version

from towerpipe.config import validate_or_exit

min_version("9.0")


configfile: "config/config.yaml"
configfile: "config/models.yaml"


# every default is in the schema; a bad config stops here with one line per problem
validate_or_exit(config, "config/schema.yaml")


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


onsuccess:
    # one line per zone assembled by this run: towers, failed blocks, the QA index
    from towerpipe.products.summary import print_summary, zones_in_log

    print_summary(zones_in_log(log))


onerror:
    # With --keep-going the other blocks completed: publish them, and the failures, in an
    # explicitly INCOMPLETE zone directory whose QA index names each failed block and why.
    from towerpipe.jobs.steps import assemble_incomplete_zone, failures_from_log
    from towerpipe.products.summary import print_summary, zones_in_log

    _failures = failures_from_log(log, WORK)
    for _zone, _failed in _failures.items():
        if _zone in config["zones"]:
            assemble_incomplete_zone(_zone, f"results/{_zone}", zone_products(_zone), _failed,
                                     run_cfg=run_params(), block_bounds=bounds(_zone), registry=registry_file(_zone),
                                     caches={b: cache_dir(_zone, b) for b in blocks(_zone)},
                                     fingerprints={b: i.fingerprint for b, i in inputs(_zone).items()},
                                     neighbours={b: p["neighbours"] for b, p in (plan_or_none(_zone) or {}).items()},
                                     stage_dir=f"{WORK}/{_zone}/published",
                                     sources={b: i.relpath for b, i in inputs(_zone).items()})
            print(f"towerpipe: results/{_zone}/ is INCOMPLETE; failed blocks: {', '.join(sorted(_failed))}")
    # then, as on success, one line per zone (the failed blocks counted)
    print_summary(sorted(set(zones_in_log(log)) | (set(_failures) & set(config["zones"]))))
