"""bayescalib: Bayesian calibration from observed interface shapes.

Run the default study:          snakemake --cores 2
Run another study:              snakemake --cores 2 --configfile config/<study>.yaml
Resume after any interruption:  the command that started the run, unchanged
HTML report:                    snakemake --report results/<study>/report.html [--configfile ...]

Parsing this file is cheap: it validates the config (JSON schema with
defaults, errors name the offending key) and imports nothing heavy; the Sobol
design is computed only when the DAG first needs a point.
"""

import os
import sys

from bayescalib.config import load_yaml, merge_layers
from bayescalib.study import Study, ConfigError

DEFAULT_CONFIG = "config/config.yaml"

configfile: DEFAULT_CONFIG

try:
    # the layers in order (defaults, --configfile files, --config values), merged so
    # that a later layer's sigma_n replaces an earlier sigma_n2 (and vice versa)
    _cli = getattr(workflow, "config_settings", None)
    if _cli is None or not hasattr(_cli, "configfiles"):  # another Snakemake: its merge
        _layers = [config]
    else:
        _files = [f for f in [DEFAULT_CONFIG] if os.path.isfile(f)] + list(_cli.configfiles)
        _layers = [load_yaml(f) for f in _files] + [dict(_cli.config)]
    study = Study(merge_layers(_layers), where="config")
except ConfigError as exc:
    sys.stderr.write(f"bayescalib: invalid configuration:\n{exc}\n")
    sys.exit(1)
for _note in study.notes:
    sys.stderr.write(f"bayescalib: note: {_note}\n")

# A command that may run jobs makes itself the one run of this study before Snakemake
# checks its lock or incomplete files: a live run of the study refuses it (never an
# unlock or a rerun over a live run); a killed run's stale lock is removed, so that the
# command that started the run also resumes it (bayescalib.execution.resume).
if workflow.is_main_process:
    from bayescalib.study import StudyBusyError, runs_jobs
    from bayescalib.execution.resume import asks_report, claim_run, report_note, report_refusal

    if runs_jobs(sys.argv):
        try:
            for _note in claim_run(study.root, study.name):
                sys.stderr.write(f"bayescalib: note: {_note}\n")
        except StudyBusyError as exc:
            sys.stderr.write(f"bayescalib: {exc}\n")
            sys.exit(1)
        # summary.json is read by no job: a damaged one is set aside here, before the
        # plan is made, so that this run writes it again (a look-only command leaves it)
        if os.path.isfile(f"{study.root}/summary.json"):
            from bayescalib.stages.errors import PipelineError
            from bayescalib.stages.files import read_stage_file

            try:
                read_stage_file(f"{study.root}/summary.json", "study summary",
                                rebuilt_by_this_run=True)
            except PipelineError as _exc:
                sys.stderr.write(f"bayescalib: {_exc}\n")
    elif asks_report(sys.argv):
        _refusal = report_refusal(study.root, study.name, sys.argv)
        if _refusal is not None:
            sys.stderr.write(f"bayescalib: no report: {_refusal}\n")
            sys.exit(1)
        if (_note := report_note(study.root, sys.argv)) is not None:
            sys.stderr.write(f"bayescalib: note: {_note}\n")

R = study.root

# the console of this run (the logger plugin the default profile names, in this process):
# a few lines per round with the solves done of the budget (bayescalib.execution.progress)
if workflow.is_main_process:
    from bayescalib.execution.progress import run_plan, set_plan

    set_plan(run_plan(
        study.name, R, active=study.active,
        budget=study.config["design"]["active"]["max_solves"] if study.active else study.n_points,
        units={p["name"]: p["unit"] for p in study.config["parameters"]}))

# the report's front page reads the study's key numbers from here (workflow.rst);
# cheap: one small JSON file, read only when it exists
from bayescalib.stages.summary import front_page

config["front_page"] = front_page(  # the posterior's figure embedded for a report only
    f"{R}/summary.json", embed_figure="--report" in {a.split("=", 1)[0] for a in sys.argv})
# what the captions may speak of: a ground truth only where every parameter has one,
# and the fields figure's solve (the ground truth's, or the posterior mean's on real data)
config["report_flags"] = {"ground_truth": study.has_ground_truth, "synthetic": study.synthetic,
                          "dim3": study.interface_dim == 3}


onstart:
    # one run of a study at a time (Snakemake's lock alone is lost when another
    # study's run ends in this directory); released by the kernel when this ends
    from bayescalib.study import StudyBusyError, hold_run_lock
    from snakemake.exceptions import WorkflowError

    try:
        hold_run_lock(R, study.name)
    except StudyBusyError as exc:
        raise WorkflowError(f"bayescalib: {exc}") from None
    # the warm process that runs the per-point jobs (solve, discrepancy) of a local
    # run; without it (cluster, or it did not start) the jobs run in-process
    # (BAYESCALIB_JOBSERVER=off: every job in its own fresh interpreter)
    if workflow.local_exec and not workflow.dryrun:
        from bayescalib.execution.jobserver import start_server

        start_server(R)

wildcard_constraints:
    i=r"\d+",
    r=r"\d+",
    k=r"\d+",
    measure=r"euclidean|cpp|rkhs",

report: "workflow/report/workflow.rst"


onsuccess:
    from bayescalib.execution.jobserver import stop_server

    stop_server()  # its log is complete when the run returns
    # the posterior in one line, then the verdict in at most three short sentences
    # (the misfit first, when the best fit is worse than the noise; converged or not
    # and why; what to do); the detail is in summary.json and the report
    from pathlib import Path as _Path

    _summary = _Path(R, "summary.json")
    if _summary.is_file():
        from bayescalib.stages.files import read_stage_file
        from bayescalib.stages.summary import run_line
        from bayescalib.stages.verdict import verdict

        _s = read_stage_file(_summary, "study summary")  # this run wrote or read it
        print(run_line(_s), flush=True)
        print(verdict(_s), flush=True)
        print(f"Detail in {_summary} and in the report (snakemake --report).", flush=True)

onerror:
    from bayescalib.execution.jobserver import stop_server

    stop_server()


include: "workflow/rules/common.smk"
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
        study_outputs,
    default_target: True
