# Training: results/models/<name>/ = checkpoint, model card, metrics, curves (+ ablation).


rule train_model:
    input:
        tiles=training_tiles(),
        init=lambda wc: init_bundle_files(wc.name),
    output:
        bundle=directory(f"{WORK}/models/{{name}}"),
    params:
        feature_set=lambda wc: model_spec(wc.name)["feature_set"],
        train=lambda wc: model_train_config(wc.name),
    log:
        f"{WORK}/models/logs/train_model/{{name}}.log",
    benchmark:
        f"{WORK}/models/benchmarks/train_model/{{name}}.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 2
    resources:
        mem_mb=8000,
        runtime=120,
    script:
        "../scripts/train_model.py"


rule ablation:
    input:
        tiles=training_tiles(),
    output:
        out=directory(f"{WORK}/ablation/{{name}}"),
    params:
        feature_set=lambda wc: model_spec(wc.name)["feature_set"],
        train=lambda wc: model_train_config(wc.name, ablation=True),
    log:
        f"{WORK}/models/logs/ablation/{{name}}.log",
    benchmark:
        f"{WORK}/models/benchmarks/ablation/{{name}}.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 2
    resources:
        mem_mb=8000,
        runtime=600,
    script:
        "../scripts/ablation.py"


rule model_results:
    input:
        bundle=f"{WORK}/models/{{name}}",
        ablation=lambda wc: [f"{WORK}/ablation/{wc.name}"] if TRAIN["ablation"] else [],
    output:
        directory("results/models/{name}/"),
    log:
        f"{WORK}/models/logs/model_results/{{name}}.log",
    benchmark:
        f"{WORK}/models/benchmarks/model_results/{{name}}.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    script:
        "../scripts/model_results.py"
