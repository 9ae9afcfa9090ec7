"""Rule `base_state`: the warm-start state at the centre of the design box."""
from bayescalib.models.forward import solve_base_state
from bayescalib.stages.logs import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
solve_base_state(
    snakemake.params.forward_model,  # noqa: F821
    snakemake.params.point,  # noqa: F821
    snakemake.output.run,  # noqa: F821
    snakemake.output.state,  # noqa: F821
)
