# GP surrogate of the log-likelihood (one per measure) and the GP convergence
# study over n_train. Depends on the training table and the surrogate section.


rule train_surrogate:
    conda:
        "../envs/bayescalib.yaml"
    input:
        training_path=f"{R}/{{measure}}/training.h5",
        reuse=lambda wc: _round_reuse(wc, "training", "surrogate"),
    output:
        out_path=f"{R}/{{measure}}/surrogate.h5",
    params:
        surrogate=study.config["surrogate"],
        parameters=study.config["parameters"],
    log:
        f"{R}/logs/{{measure}}/train_surrogate.log",
        benchmark=f"{R}/benchmarks/train_surrogate/{{measure}}.tsv",
    threads: 1
    shell:
        job(locals())


rule convergence:
    conda:
        "../envs/bayescalib.yaml"
    input:
        f"{R}/{{measure}}/training.h5",
    output:
        f"{R}/{{measure}}/convergence.json",
    params:
        surrogate=study.config["surrogate"],
        parameters=study.config["parameters"],
        convergence=study.config["convergence"],
        n_train=study.n_train,
    benchmark:
        f"{R}/benchmarks/convergence/{{measure}}.tsv"
    log:
        f"{R}/logs/{{measure}}/convergence.log",
    threads: 1
    script:
        "../../scripts/convergence.py"
