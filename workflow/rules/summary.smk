# summary.json: the study's results in the user's units (SPEC.md contract),
# with the paths of its figures.


rule summary:
    conda:
        "../envs/bayescalib.yaml"
    input:
        figure_targets(),  # made before the summary, which lists them (params.figure_map)
        posterior=expand(f"{R}/{{measure}}/posterior.json", measure=study.measures),
        training=expand(f"{R}/{{measure}}/training.h5", measure=study.measures),
        particles=expand(f"{R}/{{measure}}/particles.h5", measure=study.measures),
        convergence=expand(f"{R}/{{measure}}/convergence.json", measure=study.measures)
        if study.config["convergence"]["enabled"]
        else [],
        active=lambda wc: active_records(),
        check=[f"{R}/{study.primary_measure}/posterior_check.json"] if N_CHECK else [],
    output:
        out=report(f"{R}/summary.json", caption="../report/summary.rst", category="Summary"),
    params:
        study=study.name,
        parameters=study.config["parameters"],
        measures=study.measures,
        figure_map=figure_map(),
        root=lambda wc, output: os.path.dirname(output[0]),
        strategy=study.config["design"]["strategy"],
        n_solves=lambda wc: len(final_points()),
        # the budget the verdict speaks of (bayescalib.stages.verdict)
        budget={"max_solves": study.config["design"]["active"]["max_solves"],
                "check_draws": study.config["posterior_check"]["draws"]
                or (study.config["design"]["active"]["batch_size"]
                    if study.config["surrogate"]["target"] == "outputs" else 0)}
        if study.active else {},
    log:
        f"{R}/logs/summary.log",
    threads: 1
    shell:
        job(locals())
