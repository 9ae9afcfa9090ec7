"""Rule `solve`: one forward solve of design point `i` (always writes a run record)."""
from bayescalib.forward import solve_point
from bayescalib.pipeline import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
solve_point(
    snakemake.params.forward_model,  # noqa: F821
    snakemake.params.point,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    warm_start=snakemake.input.get("base"),  # noqa: F821
)
