"""Rule `train_surrogate`: GP surrogate of the log-likelihood."""
from bayescalib.pipeline import setup_logging, train

setup_logging(snakemake.log[0])  # noqa: F821
train(
    snakemake.input[0],  # noqa: F821
    snakemake.params.surrogate,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.output[0],  # noqa: F821
)
