"""Rule `marginalize`: posterior summaries and the ArviZ NetCDF export."""
from bayescalib.pipeline import marginalize, setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
marginalize(
    snakemake.input.particles,  # noqa: F821
    snakemake.input.surrogate,  # noqa: F821
    snakemake.params.posterior,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.params.seed,  # noqa: F821
    snakemake.output.posterior,  # noqa: F821
    snakemake.output.netcdf,  # noqa: F821
)
