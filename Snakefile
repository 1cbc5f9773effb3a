# towerpipe: power transmission towers in airborne LiDAR (Carós et al. 2022).
#   snakemake --cores 2 results/<zone>/          one zone, raw blocks in -> products out
#   snakemake --cores 2 results/models/<name>/   train the models on a training zone
from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "config/schema.yaml")


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
