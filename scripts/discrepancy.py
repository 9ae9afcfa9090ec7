"""Rule `discrepancy`: D and log-likelihood of one design point for one measure."""
from bayescalib.pipeline import discrepancy, setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
discrepancy(
    snakemake.input.run,  # noqa: F821
    snakemake.input.obs,  # noqa: F821
    snakemake.wildcards.measure,  # noqa: F821
    snakemake.params.measure,  # noqa: F821
    snakemake.params.likelihood,  # noqa: F821
    snakemake.output[0],  # noqa: F821
)
