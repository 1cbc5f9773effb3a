# Synthetic zones (the demo zone, training zones): generated when missing.


checkpoint synth_zone:
    output:
        directory("data/{zone}"),
    params:
        synth=lambda wc: config["zones"][wc.zone]["synth"],
    log:
        f"{WORK}/{{zone}}/logs/synth_zone.log",
    benchmark:
        f"{WORK}/{{zone}}/benchmarks/synth_zone.tsv"
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    script:
        "../scripts/synth_zone.py"
