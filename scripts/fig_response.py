"""Rule `fig_response`: GP log-likelihood response surfaces."""
from bayescalib.stages import setup_logging
from bayescalib.stages.figures import response_figures

setup_logging(snakemake.log[0])  # noqa: F821
response_figures(
    snakemake.input.training,  # noqa: F821
    snakemake.input.surrogate,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.params.plots,  # noqa: F821
    snakemake.params.stem,  # noqa: F821
)
