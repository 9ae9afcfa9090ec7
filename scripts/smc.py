"""Rule `smc`: sequential Monte Carlo on the surrogate."""
from bayescalib.pipeline import setup_logging, smc

setup_logging(snakemake.log[0])  # noqa: F821
smc(
    snakemake.input[0],  # noqa: F821
    snakemake.params.smc,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.output[0],  # noqa: F821
)
