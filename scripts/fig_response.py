"""Rule `fig_response`: GP log-likelihood response surfaces."""
from bayescalib.figures import response_figures
from bayescalib.pipeline import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
response_figures(
    snakemake.input.training,  # noqa: F821
    snakemake.input.surrogate,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.params.plots,  # noqa: F821
    snakemake.params.stem,  # noqa: F821
)
