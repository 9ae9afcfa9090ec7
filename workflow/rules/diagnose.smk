# Model-form diagnosis (switched on with diagnose.enabled): predictive check,
# located mismatch, attribution to candidate physics, extended calibrations and
# Bayes factors. It starts from the study's calibration (the posterior and the
# active rounds that summary.json reports). Its forward solves run inside the job
# (they depend on the posterior) through the same solve path as `solve`, in
# parallel on the job's threads, kept under diagnosis/ and reused; its extended
# calibrations are the same active-design chain as the study's (bayescalib.stages.chain).


rule diagnose:
    conda:
        "../envs/bayescalib.yaml"
    input:
        unpack(_diagnose_inputs),
    output:
        json=f"{R}/diagnosis/diagnosis.json",
        html=report(f"{R}/diagnosis/diagnosis.html", caption="../report/diagnosis_text.rst",
                    category="Diagnosis"),
        figures=report(
            shown([f"{R}/figures/diagnosis/{fam}.{ext}" for fam in
                   ("residuals", "interface_residual", "candidates") for ext in FMT]),
            caption="../report/diagnosis.rst",
            category="Diagnosis",
        ),
        figures_kept=kept([f"{R}/figures/diagnosis/{fam}.{ext}" for fam in
                           ("residuals", "interface_residual", "candidates") for ext in FMT]),
    params:
        forward_model=study.forward_section(),
        parameters=study.config["parameters"],
        observations=study.config["observations"],
        measure_name=study.primary_measure,
        measure=study.config["measure"],
        likelihood=study.config["likelihood"],
        surrogate=study.config["surrogate"],
        smc=study.config["smc"],
        posterior=study.config["posterior"],
        diagnose=study.config["diagnose"],
        design=study.config["design"],
        n_solves=lambda wildcards: len(final_points()),
        plots=study.config["plots"],
        outdir=lambda wc, output: os.path.dirname(output.json),
        figdir=lambda wc, output: os.path.dirname(output.figures[0]),
    threads: lambda wildcards: max(1, workflow.cores or 1)
    benchmark:
        f"{R}/benchmarks/diagnose.tsv"
    log:
        f"{R}/logs/diagnose.log",
    script:
        "../../scripts/diagnose.py"
