# Figures, one rule per family. Each depends on its data files and the plots
# section only, so changing a plot setting reruns only figures.

rule fig_response:
    conda:
        "../envs/bayescalib.yaml"
    input:
        training=f"{R}/{{measure}}/training.h5",
        surrogate=f"{R}/{{measure}}/surrogate.h5",
    output:
        report(
            shown([f"{R}/figures/{{measure}}/response.{ext}" for ext in FMT]),
            caption="../report/response.rst",
            category="Likelihood response surfaces",
            subcategory="{measure}",
        ),
        kept([f"{R}/figures/{{measure}}/response.{ext}" for ext in FMT]),
    params:
        parameters=study.config["parameters"],
        plots=study.config["plots"],
        stem=lambda wc, output: os.path.splitext(output[0])[0],
    log:
        f"{R}/logs/{{measure}}/fig_response.log",
    benchmark:
        f"{R}/benchmarks/figures/{{measure}}/response.tsv"
    shell:
        FIG_RESPONSE_JOB


rule fig_convergence:
    conda:
        "../envs/bayescalib.yaml"
    input:
        f"{R}/{{measure}}/convergence.json",
    output:
        report(
            shown([f"{R}/figures/{{measure}}/convergence.{ext}" for ext in FMT]),
            caption="../report/convergence.rst",
            category="GP convergence",
            subcategory="{measure}",
        ),
        kept([f"{R}/figures/{{measure}}/convergence.{ext}" for ext in FMT]),
    params:
        plots=study.config["plots"],
        stem=lambda wc, output: os.path.splitext(output[0])[0],
    log:
        f"{R}/logs/{{measure}}/fig_convergence.log",
    benchmark:
        f"{R}/benchmarks/figures/{{measure}}/convergence.tsv"
    shell:
        FIG_CONVERGENCE_JOB




rule fig_posterior:
    conda:
        "../envs/bayescalib.yaml"
    input:
        particles=f"{R}/{{measure}}/particles.h5",
        posterior=f"{R}/{{measure}}/posterior.json",
    output:
        # one named output per figure family, each with its own report caption
        **{
            fam: report(
                shown([f"{R}/figures/{{measure}}/{fam}.{ext}" for ext in FMT]),
                caption=f"../report/{fam}.rst",
                category="Posterior",
                subcategory="{measure}",
            )
            for fam in _POSTERIOR_FAMILIES
        },
        **{
            f"{fam}_kept": kept([f"{R}/figures/{{measure}}/{fam}.{ext}" for ext in FMT])
            for fam in _POSTERIOR_FAMILIES
        },
    params:
        parameters=study.config["parameters"],
        plots=study.config["plots"],
        stems=lambda wc: {
            fam: f"{R}/figures/{wc.measure}/{fam}" for fam in _POSTERIOR_FAMILIES
        },
    log:
        f"{R}/logs/{{measure}}/fig_posterior.log",
    benchmark:
        f"{R}/benchmarks/figures/{{measure}}/posterior.tsv"
    priority: 10  # on the longest chain after the SMC (rule smc)
    shell:
        FIG_POSTERIOR_JOB


rule predictive_solve:
    conda:
        "../envs/bayescalib.yaml"
    input:
        particles=f"{R}/{study.primary_measure}/particles.h5",
    output:
        f"{R}/predictive/{{k}}.h5",
    params:
        forward_model=study.forward_section(),
        parameters=study.config["parameters"],
        n=K_SOLVED,
        seed=study.config["smc"]["seed"],
    log:
        f"{R}/logs/predictive/{{k}}.log",
    benchmark:
        f"{R}/benchmarks/predictive/{{k}}.tsv"
    threads: 1
    group:
        # single-threaded forward solves batched into SLURM jobs like the design's,
        # in a group of their own: they follow the posterior, which follows the
        # design's solves, and a group may not be left and re-entered
        "predictive_solves"
    shell:
        PREDICTIVE_JOB


rule posterior_check:
    conda:
        "../envs/bayescalib.yaml"
    input:
        samples=expand(f"{R}/predictive/{{k}}.h5", k=range(K_SOLVED)),
        obs=f"{R}/observations/observations.h5",
        surrogate=f"{R}/{study.primary_measure}/surrogate.h5",
        particles=f"{R}/{study.primary_measure}/particles.h5",
    output:
        f"{R}/{study.primary_measure}/posterior_check.json",
    params:
        measure_name=study.primary_measure,
        measure=study.config["measure"][study.primary_measure],
        likelihood=study.config["likelihood"],
        parameters=study.config["parameters"],
        check=study.config["posterior_check"],
    log:
        f"{R}/logs/posterior_check.log",
    benchmark:
        f"{R}/benchmarks/posterior_check.tsv"
    threads: 1
    shell:
        POSTERIOR_CHECK_JOB


rule fig_interfaces:
    conda:
        "../envs/bayescalib.yaml"
    input:
        obs=f"{R}/observations/observations.h5",
        samples=expand(f"{R}/predictive/{{k}}.h5", k=range(K)),
        **({"truth": f"{R}/observations/ground_truth_run.h5"} if SYNTHETIC else {}),
    output:
        report(
            shown([f"{R}/figures/interfaces.{ext}" for ext in FMT]),
            caption="../report/interfaces.rst",
            category="Interfaces",
        ),
        kept([f"{R}/figures/interfaces.{ext}" for ext in FMT]),
    params:
        plots=study.config["plots"],
        stem=lambda wc, output: os.path.splitext(output[0])[0],
    log:
        f"{R}/logs/fig_interfaces.log",
    benchmark:
        f"{R}/benchmarks/figures/interfaces.tsv"
    shell:
        FIG_INTERFACES_JOB


rule posterior_mean_solve:
    # real data (no ground truth to show): the calibrated model's fields, solved at the
    # posterior mean of the primary measure
    conda:
        "../envs/bayescalib.yaml"
    input:
        posterior=f"{R}/{study.primary_measure}/posterior.json",
    output:
        run=f"{R}/posterior_mean/run.h5",
        vtu=f"{R}/posterior_mean/fields.vtu",
    params:
        forward_model=study.forward_section(),
        parameters=study.config["parameters"],
    log:
        f"{R}/logs/posterior_mean_solve.log",
    benchmark:
        f"{R}/benchmarks/posterior_mean_solve.tsv"
    threads: 1
    resources:
        runtime=30,
        mem_mb=2000,
    shell:
        POSTERIOR_MEAN_JOB

rule fig_segmentation:
    conda:
        "../envs/bayescalib.yaml"
    input:
        obs=f"{R}/observations/observations.h5",
        images=IMAGE_FILES,
    output:
        report(
            shown([f"{R}/figures/segmentation.{ext}" for ext in FMT]),
            caption="../report/segmentation.rst",
            category="Observations",
        ),
        kept([f"{R}/figures/segmentation.{ext}" for ext in FMT]),
    params:
        observations=study.config["observations"],
        plots=study.config["plots"],
        stem=lambda wc, output: os.path.splitext(output[0])[0],
    log:
        f"{R}/logs/fig_segmentation.log",
    benchmark:
        f"{R}/benchmarks/figures/segmentation.tsv"
    shell:
        FIG_SEGMENTATION_JOB


rule fig_fields:
    conda:
        "../envs/bayescalib.yaml"
    input:
        # synthetic data: the solve at the ground truth; real data: at the posterior mean
        vtu=f"{R}/observations/ground_truth.vtu" if SYNTHETIC else f"{R}/posterior_mean/fields.vtu",
        run=f"{R}/observations/ground_truth_run.h5" if SYNTHETIC else f"{R}/posterior_mean/run.h5",
    output:
        report(
            shown([f"{R}/figures/fields.{ext}" for ext in FMT]),
            caption="../report/fields.rst",
            category="Ground truth fields" if SYNTHETIC else "Fields at the posterior mean",
        ),
        kept([f"{R}/figures/fields.{ext}" for ext in FMT]),
    params:
        plots=study.config["plots"],
        stem=lambda wc, output: os.path.splitext(output[0])[0],
        **({} if SYNTHETIC else {"parameters": study.config["parameters"]}),
    log:
        f"{R}/logs/fig_fields.log",
    benchmark:
        f"{R}/benchmarks/figures/fields.tsv"
    shell:
        FIG_FIELDS_JOB


rule fig_rounds:
    conda:
        "../envs/bayescalib.yaml"
    input:
        records=lambda wc: active_records(),
        particles=lambda wc: [f"{ACTIVE_DIR}/{r}/particles.h5" for r in range(final_round() + 1)],
        training=f"{R}/{study.primary_measure}/training.h5",
    output:
        report(
            shown([f"{R}/figures/rounds.{ext}" for ext in FMT]),
            caption="../report/rounds.rst",
            category="Active design",
        ),
        kept([f"{R}/figures/rounds.{ext}" for ext in FMT]),
    params:
        parameters=study.config["parameters"],
        active=study.config["design"]["active"],
        plots=study.config["plots"],
        stem=lambda wc, output: os.path.splitext(output[0])[0],
    log:
        f"{R}/logs/fig_rounds.log",
    benchmark:
        f"{R}/benchmarks/figures/rounds.tsv"
    shell:
        FIG_ROUNDS_JOB
