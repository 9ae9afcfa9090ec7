"""Rule `predictive_solve`: forward solve at posterior draw k (interface plots)."""
from bayescalib.models.forward import solve_point
from bayescalib.stages import setup_logging
from bayescalib.stages.figures import posterior_draws

setup_logging(snakemake.log[0])  # noqa: F821
point = posterior_draws(
    snakemake.input.particles,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    int(snakemake.wildcards.k),  # noqa: F821
    snakemake.params.n,  # noqa: F821
    snakemake.params.seed,  # noqa: F821
)
solve_point(snakemake.params.forward_model, point, snakemake.output[0])  # noqa: F821
