# Active design (design.strategy: active): round 0 solves the Sobol points
# 0..n_initial-1; at the end of each round r the checkpoint `acquire` checks the
# surrogate against round r's solves, applies the stop rule and, unless it
# stops, chooses the batch of round r+1, whose points are solved as ordinary
# `solve` jobs (runs/<i>.h5, i continuing the numbering). Each round's training
# table, surrogate and SMC live under active/<r>/ and use the primary measure.
# A solve depends on its point's values (a parameter), never on the time stamp
# of the acquire file that chose it, so rerunning an acquire job with the same
# outcome re-solves nothing.

rule gather_round:
    conda:
        "../envs/bayescalib.yaml"
    input:
        unpack(_round_inputs),
    output:
        out_path=f"{ACTIVE_DIR}/{{r}}/training.h5",
    params:
        names=[p["name"] for p in study.config["parameters"]],
        targets=study.targets(),
        n_train=None,
    log:
        f"{R}/logs/active/{{r}}/gather.log",
        benchmark=f"{R}/benchmarks/gather/round_{{r}}.tsv",
    shell:
        job(locals(), "gather")


rule train_round:
    conda:
        "../envs/bayescalib.yaml"
    input:
        training_path=f"{ACTIVE_DIR}/{{r}}/training.h5",
        # the previous round's choices of the surrogate, refitted between full searches
        # (surrogate.reselect_growth, surrogate.reselect_error; rounds run in order
        # already; none in round 0: an empty input)
        previous=lambda wc: f"{ACTIVE_DIR}/{int(wc.r) - 1}/surrogate.h5" if int(wc.r) > 0 else [],
    output:
        out_path=f"{ACTIVE_DIR}/{{r}}/surrogate.h5",
    params:
        surrogate=study.config["surrogate"],
        parameters=study.config["parameters"],
    log:
        f"{R}/logs/active/{{r}}/train_surrogate.log",
        benchmark=f"{R}/benchmarks/train_surrogate/round_{{r}}.tsv",
    threads: 2  # alone in its round: a full search's candidates on both cores (same fit)
    shell:
        job(locals(), "train_surrogate")


rule smc_round:
    conda:
        "../envs/bayescalib.yaml"
    input:
        surrogate_path=f"{ACTIVE_DIR}/{{r}}/surrogate.h5",
    output:
        out_path=f"{ACTIVE_DIR}/{{r}}/particles.h5",
    params:
        smc_cfg=study.round_smc,
        parameters=study.config["parameters"],
    log:
        f"{R}/logs/active/{{r}}/smc.log",
        benchmark=f"{R}/benchmarks/smc/round_{{r}}.tsv",
    threads: 2  # alone in its round: the surrogate's chunks on both cores (same particles)
    shell:
        job(locals(), "smc")


checkpoint acquire:
    conda:
        "../envs/bayescalib.yaml"
    input:
        training_path=f"{ACTIVE_DIR}/{{r}}/training.h5",
        surrogate_path=f"{ACTIVE_DIR}/{{r}}/surrogate.h5",
        particles_path=f"{ACTIVE_DIR}/{{r}}/particles.h5",
        previous_path=lambda wc: _acquire_path(int(wc.r) - 1) if int(wc.r) > 0 else [],
    output:
        out_path=f"{ACTIVE_DIR}/{{r}}/acquire.json",
    params:
        active=study.config["design"]["active"],
        check=study.config["posterior_check"],
        parameters=study.config["parameters"],
        round_index=lambda wc: int(wc.r),
    log:
        f"{R}/logs/active/{{r}}/acquire.log",
        benchmark=f"{R}/benchmarks/acquire/{{r}}.tsv",
    threads: 1
    shell:
        job(locals())
