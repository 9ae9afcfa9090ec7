"""Rule `diagnose`: model-form diagnosis of the calibrated study."""
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
