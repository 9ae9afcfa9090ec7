"""Rule `summary`: summary.json of the study."""
from bayescalib.pipeline import collect_timings, setup_logging, summary

setup_logging(snakemake.log[0])  # noqa: F821
summary(
    snakemake.params.study,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.params.measures,  # noqa: F821
    snakemake.input.posterior,  # noqa: F821
    snakemake.input.training,  # noqa: F821
    snakemake.input.particles,  # noqa: F821
    snakemake.params.figure_map,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    extra={"timings_s": collect_timings(snakemake.params.root),  # noqa: F821
           "convergence": list(snakemake.input.convergence)},  # noqa: F821
)
