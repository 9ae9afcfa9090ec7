"""bayescalib: Bayesian calibration from observed interface shapes.

Run the default study:          snakemake --cores 2
Run another study:              snakemake --cores 2 --configfile config/<study>.yaml
HTML report:                    snakemake --report results/report.html [--configfile ...]

Parsing this file is cheap: it validates the config (JSON schema with
defaults, errors name the offending key) and imports nothing heavy; the Sobol
design is computed only when the DAG first needs a point.
"""

import sys

from bayescalib.study import Study, ConfigError

configfile: "config/config.yaml"

try:
    study = Study(config, where="config")
except ConfigError as exc:
    sys.stderr.write(f"bayescalib: invalid configuration:\n{exc}\n")
    sys.exit(1)

R = study.root


onstart:
    # one run of a study at a time (Snakemake's lock alone is lost when another
    # study's run ends in this directory); released by the kernel when this ends
    from bayescalib.study import StudyBusyError, hold_run_lock
    from snakemake.exceptions import WorkflowError

    try:
        hold_run_lock(R, study.name)
    except StudyBusyError as exc:
        raise WorkflowError(f"bayescalib: {exc}") from None

wildcard_constraints:
    i=r"\d+",
    r=r"\d+",
    k=r"\d+",
    measure=r"euclidean|cpp|rkhs",

report: "workflow/report/workflow.rst"


onsuccess:
    # one plain line: the posterior, whether it converged, the solves used
    from pathlib import Path as _Path

    _summary = _Path(R, "summary.json")
    if _summary.is_file():
        from bayescalib.pipeline import read_json, run_line

        _s = read_json(_summary)
        print(run_line(_s), flush=True)
        if (_s.get("design") or {}).get("converged") is False:
            print("WARNING: " + _s["design"]["reason"], flush=True)

include: "workflow/rules/observe.smk"
include: "workflow/rules/active.smk"
include: "workflow/rules/solve.smk"
include: "workflow/rules/discrepancy.smk"
include: "workflow/rules/surrogate.smk"
include: "workflow/rules/inference.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/summary.smk"
include: "workflow/rules/diagnose.smk"


rule all:
    input:
        f"{R}/summary.json",
        *([f"{R}/diagnosis/diagnosis.json"] if study.config["diagnose"]["enabled"] else []),
    default_target: True
