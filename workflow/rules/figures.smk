# Figures, one rule per family. Each depends on its data files and the plots
# section only, so changing a plot setting reruns only figures.

rule fig_response:
    conda:
        "../envs/bayescalib.yaml"
    input:
        training_path=f"{R}/{{measure}}/training.h5",
        surrogate_path=f"{R}/{{measure}}/surrogate.h5",
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
        benchmark=f"{R}/benchmarks/figures/{{measure}}/response.tsv",
    shell:
        job(locals())


rule fig_convergence:
    conda:
        "../envs/bayescalib.yaml"
    input:
        convergence_path=f"{R}/{{measure}}/convergence.json",
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
        benchmark=f"{R}/benchmarks/figures/{{measure}}/convergence.tsv",
    shell:
        job(locals())




rule fig_posterior:
    conda:
        "../envs/bayescalib.yaml"
    input:
        particles_path=f"{R}/{{measure}}/particles.h5",
        posterior_path=f"{R}/{{measure}}/posterior.json",
    output:
        # one output per figure family, each with its own report caption (unnamed: the
        # stage writes them under params.stems)
        *[
            report(
                shown([f"{R}/figures/{{measure}}/{fam}.{ext}" for ext in FMT]),
                caption=f"../report/{fam}.rst",
                category="Posterior",
                subcategory="{measure}",
            )
            for fam in _POSTERIOR_FAMILIES
        ],
        *[kept([f"{R}/figures/{{measure}}/{fam}.{ext}" for ext in FMT])
          for fam in _POSTERIOR_FAMILIES],
    params:
        parameters=study.config["parameters"],
        plots=study.config["plots"],
        stems=lambda wc: {
            fam: f"{R}/figures/{wc.measure}/{fam}" for fam in _POSTERIOR_FAMILIES
        },
    log:
        f"{R}/logs/{{measure}}/fig_posterior.log",
        benchmark=f"{R}/benchmarks/figures/{{measure}}/posterior.tsv",
    priority: 10  # on the longest chain after the SMC (rule smc)
    shell:
        job(locals())


rule predictive_solve:
    conda:
        "../envs/bayescalib.yaml"
    input:
        particles=f"{R}/{study.primary_measure}/particles.h5",
    output:
        out=f"{R}/predictive/{{k}}.h5",
    params:
        forward_model=study.forward_section(),
        parameters=study.config["parameters"],
        k=lambda wc: int(wc.k),
        n=K_SOLVED,
        seed=study.config["smc"]["seed"],
    log:
        f"{R}/logs/predictive/{{k}}.log",
        benchmark=f"{R}/benchmarks/predictive/{{k}}.tsv",
    threads: 1
    group:
        # single-threaded forward solves batched into SLURM jobs like the design's,
        # in a group of their own: they follow the posterior, which follows the
        # design's solves, and a group may not be left and re-entered
        "predictive_solves"
    shell:
        job(locals())


rule posterior_check:
    conda:
        "../envs/bayescalib.yaml"
    input:
        sample_runs=expand(f"{R}/predictive/{{k}}.h5", k=range(K_SOLVED)),
        obs_path=f"{R}/observations/observations.h5",
        surrogate_path=f"{R}/{study.primary_measure}/surrogate.h5",
        particles_path=f"{R}/{study.primary_measure}/particles.h5",
    output:
        out_path=f"{R}/{study.primary_measure}/posterior_check.json",
    params:
        measure_name=study.primary_measure,
        measure=study.config["measure"][study.primary_measure],
        likelihood=study.config["likelihood"],
        parameters=study.config["parameters"],
        check=study.config["posterior_check"],
    log:
        f"{R}/logs/posterior_check.log",
        benchmark=f"{R}/benchmarks/posterior_check.tsv",
    threads: 1
    shell:
        job(locals())


rule fig_interfaces:
    conda:
        "../envs/bayescalib.yaml"
    input:
        obs_path=f"{R}/observations/observations.h5",
        sample_runs=expand(f"{R}/predictive/{{k}}.h5", k=range(K)),
        **({"ground_truth_run": f"{R}/observations/ground_truth_run.h5"} if SYNTHETIC else {}),
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
        benchmark=f"{R}/benchmarks/figures/interfaces.tsv",
    shell:
        job(locals())


rule posterior_mean_solve:
    # real data (no ground truth to show): the calibrated model's fields, solved at the
    # posterior mean of the primary measure
    conda:
        "../envs/bayescalib.yaml"
    input:
        posterior_path=f"{R}/{study.primary_measure}/posterior.json",
    output:
        out_path=f"{R}/posterior_mean/run.h5",
        vtu_path=f"{R}/posterior_mean/fields.vtu",
    params:
        forward_model=study.forward_section(),
        parameters=study.config["parameters"],
    log:
        f"{R}/logs/posterior_mean_solve.log",
        benchmark=f"{R}/benchmarks/posterior_mean_solve.tsv",
    threads: 1
    resources:
        runtime=30,
        mem_mb=2000,
    shell:
        job(locals())

rule fig_segmentation:
    conda:
        "../envs/bayescalib.yaml"
    input:
        IMAGE_FILES,  # a trigger: the segmentation is in observations.h5
        obs_path=f"{R}/observations/observations.h5",
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
        benchmark=f"{R}/benchmarks/figures/segmentation.tsv",
    shell:
        job(locals())


rule fig_fields:
    conda:
        "../envs/bayescalib.yaml"
    input:
        # synthetic data: the solve at the ground truth; real data: at the posterior mean
        vtu_path=f"{R}/observations/ground_truth.vtu" if SYNTHETIC
        else f"{R}/posterior_mean/fields.vtu",
        run_path=f"{R}/observations/ground_truth_run.h5" if SYNTHETIC
        else f"{R}/posterior_mean/run.h5",
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
        **({} if SYNTHETIC else {"at": "posterior_mean", "parameters": study.config["parameters"]}),
        **({} if SECTION_Z is None else {"section_z": SECTION_Z}),
    log:
        f"{R}/logs/fig_fields.log",
        benchmark=f"{R}/benchmarks/figures/fields.tsv",
    shell:
        job(locals())


rule fig_rounds:
    conda:
        "../envs/bayescalib.yaml"
    input:
        acquire_paths=lambda wc: active_records(),
        particles_paths=lambda wc: [f"{ACTIVE_DIR}/{r}/particles.h5" for r in range(final_round() + 1)],
        training_path=f"{R}/{study.primary_measure}/training.h5",
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
        benchmark=f"{R}/benchmarks/figures/rounds.tsv",
    shell:
        job(locals())
