"""Rule `observe`: the observation set (synthetic or from files)."""
from bayescalib.stages.logs import setup_logging
from bayescalib.stages.observe import observe

setup_logging(snakemake.log[0])  # noqa: F821
observe(
    snakemake.params.observations,  # noqa: F821
    snakemake.output[0],  # noqa: F821
    ground_truth_run=snakemake.input.get("run"),  # noqa: F821
)
