"""Rule `fig_posterior`: joint, particles, marginals, pairs, parallel axes."""
from bayescalib.stages import setup_logging
from bayescalib.stages.figures import posterior_figures

setup_logging(snakemake.log[0])  # noqa: F821
posterior_figures(
    snakemake.input.particles,  # noqa: F821
    snakemake.input.posterior,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.params.plots,  # noqa: F821
    snakemake.params.stems,  # noqa: F821
)
