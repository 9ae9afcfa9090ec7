# Observation set: synthetic (a forward solve at the ground truth, plus optional
# noise) or read from files/images. Depends on the forward model (synthetic
# case) and the observations section only.


rule observe:
    output:
        obs=f"{R}/observations/observations.h5",
        run=f"{R}/observations/ground_truth_run.h5",
    params:
        observations=study.config["observations"],
        forward_model=study.forward_section(),
        ground_truth=study.ground_truth(),
    log:
        f"{R}/logs/observe.log",
    threads: 1
    resources:
        runtime=30,
        mem_mb=2000,
    script:
        "../../scripts/observe.py"
