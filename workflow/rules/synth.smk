# Synthetic zones (the demo zone, training zones): generated when missing.


checkpoint synth_zone:
    output:
        directory("data/{zone}"),
    log:
        log_of("synth_zone"),
    benchmark:
        benchmark_of("synth_zone")
    conda:
        "../envs/towerpipe.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        synth=lambda wc: config["zones"][wc.zone]["synth"],
    script:
        "../scripts/synth_zone.py"
