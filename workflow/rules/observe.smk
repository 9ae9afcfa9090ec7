# Observation set: synthetic (a forward solve at the ground truth, plus optional
# seeded noise) or read from files/images. Depends on the forward model
# (synthetic case) and the observations section only.


# real data (observations.source: files) have no ground truth and no solve at it
if SYNTHETIC:

    rule ground_truth:
        conda:
            "../envs/bayescalib.yaml"
        output:
            run=f"{R}/observations/ground_truth_run.h5",
            **({"vtu": f"{R}/observations/ground_truth.vtu"} if FIELDS else {}),
        params:
            forward_model=study.forward_section(),
            point=study.ground_truth_point(),
        benchmark:
            f"{R}/benchmarks/ground_truth.tsv"
        log:
            f"{R}/logs/ground_truth.log",
        threads: 1
        # the observations gate every discrepancy: made first, so that the discrepancies run
        # beside the solves (with the priorities of the rules after the SMC and none here,
        # Snakemake ran these two after all solves)
        priority: 40
        resources:
            runtime=30,
            mem_mb=2000,
        script:
            "../../scripts/ground_truth.py"


rule observe:
    conda:
        "../envs/bayescalib.yaml"
    input:
        unpack(_observe_inputs),
    output:
        f"{R}/observations/observations.h5",
    params:
        observations=study.config["observations"],
    benchmark:
        f"{R}/benchmarks/observe.tsv"
    log:
        f"{R}/logs/observe.log",
    threads: 1
    priority: 40  # as ground_truth (synthetic data)
    script:
        "../../scripts/observe.py"
