"""Rule `diagnose`: model-form diagnosis of the calibrated study."""
import os

# One BLAS thread, as in the workflow's other jobs (bayescalib.execution.jobserver), set
# before numpy is imported: Snakemake gives this job's BLAS all its threads (the cores),
# which its solve workers use as processes. Its GP fits are small matrices that gain
# nothing from BLAS threads, and on a shared 2-core machine two OpenBLAS threads cost a
# full surrogate search 13x the wall time and 25x the CPU time of one (sloppy4d, 80
# points, 12 candidates: 378 s / 56 s against 28 s / 2.2 s at load 12-22;
# OPENBLAS_NUM_THREADS=2 or 1 python benchmarks/bench_search_threads.py --problems
# sloppy4d --n 80 --threads 1; docs/surrogate.md, issue 38).
from bayescalib.execution.jobserver import JOB_BLAS_ENV  # imports no NumPy

os.environ.update(JOB_BLAS_ENV)

from bayescalib.diagnosis.report import write_diagnosis
from bayescalib.diagnosis.stage import run_diagnosis
from bayescalib.stages.logs import setup_logging
from bayescalib.stages.summary import design_summary

sm = snakemake  # noqa: F821
setup_logging(sm.log[0])
p = sm.params
diagnosis, checks = run_diagnosis(
    fm=p.forward_model, parameters=p.parameters, observations=p.observations,
    measure_name=p.measure_name, measure=p.measure, likelihood=p.likelihood,
    surrogate=p.surrogate, smc_cfg=p.smc, posterior_cfg=p.posterior, diagnose=p.diagnose,
    active=p.design["active"],
    design=design_summary(p.design["strategy"], sm.input.rounds, p.n_solves),
    particles_path=sm.input.particles, training_path=sm.input.training,
    posterior_path=sm.input.posterior, obs_path=sm.input.obs, outdir=p.outdir,
    workers=sm.threads, warm_start=sm.input.get("base"),
)
write_diagnosis(diagnosis, checks, json_path=sm.output.json, html_path=sm.output.html,
                figdir=p.figdir, formats=p.plots["formats"], dpi=p.plots["dpi"])
