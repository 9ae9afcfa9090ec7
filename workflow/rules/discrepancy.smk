# Discrepancy between model and observed interfaces, one job per design point
# and measure: distance vector, D, log-likelihood. Depends on this measure's own
# options (e.g. sigma_W) and the likelihood section (sigma_N), never on the forward
# model settings or another measure's options.


rule discrepancy:
    conda:
        "../envs/bayescalib.yaml"
    input:
        run_path=f"{R}/runs/{{i}}.h5",
        obs_path=f"{R}/observations/observations.h5",
    output:
        out_path=f"{R}/discrepancy/{{measure}}/{{i}}.json",
    params:
        measure_name=lambda wc: wc.measure,
        measure=lambda wc: study.config["measure"][wc.measure],
        likelihood=study.config["likelihood"],
    log:
        f"{R}/logs/discrepancy/{{measure}}/{{i}}.log",
        benchmark=f"{R}/benchmarks/discrepancy/{{measure}}/{{i}}.tsv",
    threads: 1
    resources:
        runtime=5,
        mem_mb=1000,
    shell:
        job(locals())


rule gather:
    conda:
        "../envs/bayescalib.yaml"
    input:
        run_paths=lambda wc: [f"{R}/runs/{i}.h5" for i in final_points()],
        disc_paths=lambda wc: [f"{R}/discrepancy/{wc.measure}/{i}.json" for i in final_points()],
    output:
        out_path=f"{R}/{{measure}}/training.h5",
    params:
        _set_aside,  # a rerun trigger only (unnamed: not an argument of gather)
        names=[p["name"] for p in study.config["parameters"]],
        targets=study.targets(),
        n_train=None if study.active else study.n_train,
    log:
        f"{R}/logs/{{measure}}/gather.log",
        benchmark=f"{R}/benchmarks/gather/{{measure}}.tsv",
    shell:
        job(locals())
