# Figures, one rule per family. Each depends on its data files and the plots
# section only, so changing a plot setting reruns only figures.

FMT = study.config["plots"]["formats"]
K = study.config["plots"]["n_interface_samples"]
DIM = len(study.config["parameters"])


def _fig(name, measure=None):
    base = f"{R}/figures/{measure}/{name}" if measure else f"{R}/figures/{name}"
    return [f"{base}.{ext}" for ext in FMT]


def figure_map():
    """Figure family -> list of files (for summary.json and rule all)."""
    out = {}
    for m in study.measures:
        if DIM >= 2:
            out[f"{m}/response"] = _fig("response", m)
            out[f"{m}/joint"] = _fig("joint", m)
            out[f"{m}/particles"] = _fig("particles", m)
        out[f"{m}/marginals"] = _fig("marginals", m)
        out[f"{m}/pairs"] = _fig("pairs", m)
        out[f"{m}/parallel"] = _fig("parallel", m)
        if study.config["convergence"]["enabled"]:
            out[f"{m}/convergence"] = _fig("convergence", m)
    if study.active and DIM >= 2:
        out["rounds"] = _fig("rounds")
    if K > 0:
        out["interfaces"] = _fig("interfaces")
    if FIELDS:
        out["fields"] = _fig("fields")
    return out


def figure_targets():
    return [f for files in figure_map().values() for f in files]


rule fig_response:
    input:
        training=f"{R}/{{measure}}/training.h5",
        surrogate=f"{R}/{{measure}}/surrogate.h5",
    output:
        report(
            [f"{R}/figures/{{measure}}/response.{ext}" for ext in FMT],
            caption="../report/response.rst",
            category="Likelihood response surfaces",
            subcategory="{measure}",
        ),
    params:
        parameters=study.config["parameters"],
        plots=study.config["plots"],
        stem=lambda wc: f"{R}/figures/{wc.measure}/response",
    log:
        f"{R}/logs/{{measure}}/fig_response.log",
    benchmark:
        f"{R}/benchmarks/figures/{{measure}}/response.tsv"
    script:
        "../../scripts/fig_response.py"


rule fig_convergence:
    input:
        f"{R}/{{measure}}/convergence.json",
    output:
        report(
            [f"{R}/figures/{{measure}}/convergence.{ext}" for ext in FMT],
            caption="../report/convergence.rst",
            category="GP convergence",
            subcategory="{measure}",
        ),
    params:
        plots=study.config["plots"],
        stem=lambda wc: f"{R}/figures/{wc.measure}/convergence",
    log:
        f"{R}/logs/{{measure}}/fig_convergence.log",
    benchmark:
        f"{R}/benchmarks/figures/{{measure}}/convergence.tsv"
    script:
        "../../scripts/fig_convergence.py"


_POSTERIOR_FAMILIES = (["joint", "particles"] if DIM >= 2 else []) + [
    "marginals",
    "pairs",
    "parallel",
]


rule fig_posterior:
    input:
        particles=f"{R}/{{measure}}/particles.h5",
        posterior=f"{R}/{{measure}}/posterior.json",
    output:
        # one named output per figure family, each with its own report caption
        **{
            fam: report(
                [f"{R}/figures/{{measure}}/{fam}.{ext}" for ext in FMT],
                caption=f"../report/{fam}.rst",
                category="Posterior",
                subcategory="{measure}",
            )
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
    script:
        "../../scripts/fig_posterior.py"


rule predictive_solve:
    input:
        particles=f"{R}/{study.primary_measure}/particles.h5",
    output:
        f"{R}/predictive/{{k}}.h5",
    params:
        forward_model=study.forward_section(),
        parameters=study.config["parameters"],
        n=K,
        seed=study.config["smc"]["seed"],
    log:
        f"{R}/logs/predictive/{{k}}.log",
    benchmark:
        f"{R}/benchmarks/predictive/{{k}}.tsv"
    threads: 1
    script:
        "../../scripts/predictive_solve.py"


rule fig_interfaces:
    input:
        obs=f"{R}/observations/observations.h5",
        samples=expand(f"{R}/predictive/{{k}}.h5", k=range(K)),
        **(
            {"truth": f"{R}/observations/ground_truth_run.h5"}
            if study.config["observations"].get("source", "synthetic") == "synthetic"
            else {}
        ),
    output:
        report(
            [f"{R}/figures/interfaces.{ext}" for ext in FMT],
            caption="../report/interfaces.rst",
            category="Interfaces",
        ),
    params:
        plots=study.config["plots"],
        stem=f"{R}/figures/interfaces",
    log:
        f"{R}/logs/fig_interfaces.log",
    benchmark:
        f"{R}/benchmarks/figures/interfaces.tsv"
    script:
        "../../scripts/fig_interfaces.py"


rule fig_fields:
    input:
        vtu=f"{R}/observations/ground_truth.vtu",
        run=f"{R}/observations/ground_truth_run.h5",
    output:
        report(
            [f"{R}/figures/fields.{ext}" for ext in FMT],
            caption="../report/fields.rst",
            category="Ground truth fields",
        ),
    params:
        plots=study.config["plots"],
        stem=f"{R}/figures/fields",
    log:
        f"{R}/logs/fig_fields.log",
    benchmark:
        f"{R}/benchmarks/figures/fields.tsv"
    script:
        "../../scripts/fig_fields.py"


rule fig_rounds:
    input:
        records=lambda wc: active_records(),
        particles=lambda wc: [f"{ACTIVE_DIR}/{r}/particles.h5" for r in range(final_round() + 1)],
        training=f"{R}/{study.primary_measure}/training.h5",
    output:
        report(
            [f"{R}/figures/rounds.{ext}" for ext in FMT],
            caption="../report/rounds.rst",
            category="Active design",
        ),
    params:
        parameters=study.config["parameters"],
        active=study.config["design"]["active"],
        plots=study.config["plots"],
        stem=f"{R}/figures/rounds",
    log:
        f"{R}/logs/fig_rounds.log",
    benchmark:
        f"{R}/benchmarks/figures/rounds.tsv"
    script:
        "../../scripts/fig_rounds.py"
