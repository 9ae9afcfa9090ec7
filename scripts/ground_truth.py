"""Rule `ground_truth`: the forward solve at the ground-truth parameters."""
from bayescalib.models.forward import solve_point
from bayescalib.stages.logs import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
vtu = snakemake.output.get("vtu")  # noqa: F821
solve_point(
    snakemake.params.forward_model,  # noqa: F821
    snakemake.params.point,  # noqa: F821
    snakemake.output.run,  # noqa: F821
    extra_outputs={"vtu": vtu} if vtu else None,
)
