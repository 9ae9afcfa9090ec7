# Discrepancy between model and observed interfaces, one job per design point
# and measure: distance vector, D, log-likelihood. Depends on this measure's own
# options (e.g. sigma_W) and the likelihood section (sigma_N), never on the forward
# model settings or another measure's options.


rule discrepancy:
    conda:
        "../envs/bayescalib.yaml"
    input:
        run=f"{R}/runs/{{i}}.h5",
        obs=f"{R}/observations/observations.h5",
    output:
        f"{R}/discrepancy/{{measure}}/{{i}}.json",
    params:
        measure=lambda wc: study.config["measure"][wc.measure],
        likelihood=study.config["likelihood"],
    benchmark:
        f"{R}/benchmarks/discrepancy/{{measure}}/{{i}}.tsv"
    log:
        f"{R}/logs/discrepancy/{{measure}}/{{i}}.log",
    threads: 1
    resources:
        runtime=5,
        mem_mb=1000,
    shell:
        DISCREPANCY_JOB


rule gather:
    conda:
        "../envs/bayescalib.yaml"
    input:
        runs=lambda wc: [f"{R}/runs/{i}.h5" for i in final_points()],
        disc=lambda wc: [f"{R}/discrepancy/{wc.measure}/{i}.json" for i in final_points()],
    output:
        f"{R}/{{measure}}/training.h5",
    params:
        names=[p["name"] for p in study.config["parameters"]],
        targets=study.targets(),
        n_train=None if study.active else study.n_train,
        set_aside=_set_aside,
    benchmark:
        f"{R}/benchmarks/gather/{{measure}}.tsv"
    log:
        f"{R}/logs/{{measure}}/gather.log",
    shell:
        GATHER_JOB
