"""Rule `predictive_solve`: forward solve at posterior draw k (interface plots)."""
from bayescalib.figures import posterior_draws
from bayescalib.forward import solve_point
from bayescalib.pipeline import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
point = posterior_draws(
    snakemake.input.particles,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    int(snakemake.wildcards.k),  # noqa: F821
    snakemake.params.n,  # noqa: F821
    snakemake.params.seed,  # noqa: F821
)
solve_point(snakemake.params.forward_model, point, snakemake.output[0])  # noqa: F821
