# Sequential Monte Carlo on the surrogate, then posterior analysis
# (moments, MAP, MAP after marginalizing uncertain conditions, Gaussian and
# Laplace approximations, KDE marginals) and the ArviZ NetCDF export.


rule smc:
    conda:
        "../envs/bayescalib.yaml"
    input:
        surrogate_path=f"{R}/{{measure}}/surrogate.h5",
        # the rounds' particles are the result only when the rounds sampled with the
        # study's settings (design.active.smc empty)
        reuse=lambda wc: _round_reuse(wc, "surrogate", "particles")
        if study.round_smc == study.config["smc"] else [],
    output:
        out_path=f"{R}/{{measure}}/particles.h5",
    params:
        smc_cfg=study.config["smc"],
        parameters=study.config["parameters"],
    log:
        f"{R}/logs/{{measure}}/smc.log",
        benchmark=f"{R}/benchmarks/smc/{{measure}}.tsv",
    # the surrogate's chunks on both cores (the same particles, bitwise: tests/test_surrogate.py);
    # Snakemake lowers it to --cores where fewer, and runs it when two cores are free
    threads: 2
    # after the SMC the longest chain is marginalize -> fig_posterior -> summary: its jobs
    # go before the other ready ones (fig_response, predictive solves), which fill the
    # other core
    priority: 30
    shell:
        job(locals())


rule marginalize:
    conda:
        "../envs/bayescalib.yaml"
    input:
        particles_path=f"{R}/{{measure}}/particles.h5",
        surrogate_path=f"{R}/{{measure}}/surrogate.h5",
    output:
        out_json=f"{R}/{{measure}}/posterior.json",
        out_netcdf=f"{R}/{{measure}}/posterior.nc",
    params:
        posterior_cfg=study.config["posterior"],
        parameters=study.config["parameters"],
        seed=study.config["smc"]["seed"],
    log:
        f"{R}/logs/{{measure}}/marginalize.log",
        benchmark=f"{R}/benchmarks/marginalize/{{measure}}.tsv",
    threads: 1
    priority: 20
    shell:
        job(locals())
