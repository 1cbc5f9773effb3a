# Training: results/models/<name>/ = checkpoint, model card, metrics, curves (+ ablation).


rule training_windows:
    input:
        tiles=training_tiles(),
    output:
        windows=f"{WORK}/models/windows.npz",
    params:
        dataset=TRAIN["dataset"],
        truth=training_truth(),
    log:
        f"{WORK}/models/logs/training_windows.log",
    benchmark:
        f"{WORK}/models/benchmarks/training_windows.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=8000,
        runtime=60,
    script:
        "../scripts/training_windows.py"


rule train_model:
    input:
        windows=f"{WORK}/models/windows.npz",
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


rule realshape_benchmark:
    input:
        tiles=lambda wc: [p for z in realshape_zones() for p in tile_files(z)],
        models=lambda wc: [d for per in loso_models().values() for d in per.values()],
    output:
        directory("results/benchmark/realshape/"),
    params:
        loso=lambda wc: loso_models(),
        zones=lambda wc: {z: zone_input(z) for z in realshape_zones()},
        inference=INFER,
        towers=TOWERS,
    log:
        f"{WORK}/models/logs/realshape_benchmark.log",
    benchmark:
        f"{WORK}/models/benchmarks/realshape_benchmark.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 2
    resources:
        mem_mb=6000,
        runtime=120,
    script:
        "../scripts/realshape_benchmark.py"
