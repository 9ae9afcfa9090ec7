# One forward solve per design point (wildcard i = point index). The job's
# params are the forward-model section and the values of point i only, so a
# change of any downstream setting never reruns it, and growing the design
# solves only the new points. A failed solve writes a failed-run record.
# Points of active rounds are read from the round record that chose them
# (active.smk).


rule base_state:
    conda:
        "../envs/bayescalib.yaml"
    output:
        run=f"{R}/runs/base_state.h5",
        state=f"{R}/runs/base_state.state.npz",
    params:
        forward_model=study.forward_section(),
        point=study.prior_centre(),
    benchmark:
        f"{R}/benchmarks/base_state.tsv"
    log:
        f"{R}/logs/solve/base_state.log",
    threads: 1
    resources:
        runtime=30,
        mem_mb=2000,
    script:
        "../../scripts/base_state.py"


rule solve:
    conda:
        "../envs/bayescalib.yaml"
    input:
        _chosen_by,  # active design: the round record that chose the point (a trigger)
        unpack(_solve_inputs),  # base: the warm-start state
    output:
        out=f"{R}/runs/{{i}}.h5",
    params:
        forward_model=study.forward_section(),
        point=lambda wc: point_values(wc.i),
    log:
        f"{R}/logs/solve/{{i}}.log",
        benchmark=f"{R}/benchmarks/solve/{{i}}.tsv",
    threads: 1
    resources:
        runtime=30,
        mem_mb=2000,
    group:
        "solves"
    shell:
        job(locals(), recorded=SOLVE_RECORDED)
