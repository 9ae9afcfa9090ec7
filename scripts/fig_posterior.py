"""Rule `fig_posterior`: joint, particles, marginals, pairs, parallel axes."""
from bayescalib.figures import posterior_figures
from bayescalib.pipeline import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
posterior_figures(
    snakemake.input.particles,  # noqa: F821
    snakemake.input.posterior,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.params.plots,  # noqa: F821
    snakemake.params.stems,  # noqa: F821
)
