"""Rule `convergence`: GP error over n_train on held-out Sobol points."""
from bayescalib.stages.convergence import convergence
from bayescalib.stages.logs import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
convergence(
    snakemake.input[0],  # noqa: F821
    snakemake.params.surrogate,  # noqa: F821
    snakemake.params.parameters,  # noqa: F821
    snakemake.params.convergence["n_train"],  # noqa: F821
    snakemake.output[0],  # noqa: F821
)
