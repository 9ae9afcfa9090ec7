# Sequential Monte Carlo on the surrogate, then posterior analysis
# (moments, MAP, MAP after marginalizing uncertain conditions, Gaussian and
# Laplace approximations, KDE marginals) and the ArviZ NetCDF export.


rule smc:
    conda:
        "../envs/bayescalib.yaml"
    input:
        surrogate=f"{R}/{{measure}}/surrogate.h5",
        # the rounds' particles are the result only when the rounds sampled with the
        # study's settings (design.active.smc empty)
        reuse=lambda wc: _round_reuse(wc, "surrogate", "particles")
        if study.round_smc == study.config["smc"] else [],
    output:
        f"{R}/{{measure}}/particles.h5",
    params:
        smc=study.config["smc"],
        parameters=study.config["parameters"],
    benchmark:
        f"{R}/benchmarks/smc/{{measure}}.tsv"
    log:
        f"{R}/logs/{{measure}}/smc.log",
    # the surrogate's chunks on both cores (the same particles, bitwise: tests/test_surrogate.py);
    # Snakemake lowers it to --cores where fewer, and runs it when two cores are free
    threads: 2
    # after the SMC the longest chain is marginalize -> fig_posterior -> summary: its jobs
    # go before the other ready ones (fig_response, predictive solves), which fill the
    # other core
    priority: 30
    shell:
        SMC_MEASURE_JOB


rule marginalize:
    conda:
        "../envs/bayescalib.yaml"
    input:
        particles=f"{R}/{{measure}}/particles.h5",
        surrogate=f"{R}/{{measure}}/surrogate.h5",
    output:
        posterior=f"{R}/{{measure}}/posterior.json",
        netcdf=f"{R}/{{measure}}/posterior.nc",
    params:
        posterior=study.config["posterior"],
        parameters=study.config["parameters"],
        seed=study.config["smc"]["seed"],
    benchmark:
        f"{R}/benchmarks/marginalize/{{measure}}.tsv"
    log:
        f"{R}/logs/{{measure}}/marginalize.log",
    threads: 1
    priority: 20
    shell:
        MARGINALIZE_JOB
