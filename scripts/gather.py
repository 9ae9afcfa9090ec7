"""Rule `gather`: the training table of one measure."""
from bayescalib.pipeline import gather, setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
gather(
    snakemake.input.runs,  # noqa: F821
    snakemake.input.disc,  # noqa: F821
    snakemake.params.names,  # noqa: F821
    snakemake.params.targets,  # noqa: F821
    snakemake.params.n_train,  # noqa: F821
    snakemake.output[0],  # noqa: F821
)
