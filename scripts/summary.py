"""Rule `summary`: summary.json of the study."""
from bayescalib.stages import collect_timings, design_summary, setup_logging, summary

sm = snakemake  # noqa: F821
setup_logging(sm.log[0])
extra = {"design": design_summary(sm.params.strategy, sm.input.active, sm.params.n_solves),
         "timings_s": collect_timings(sm.params.root)}
if sm.input.convergence:
    extra["gp_convergence"] = list(sm.input.convergence)
summary(sm.params.study, sm.params.parameters, sm.params.measures, sm.input.posterior,
        sm.input.training, sm.input.particles, sm.params.figure_map, sm.output[0], extra=extra)
