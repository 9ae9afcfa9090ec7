"""Rule `fig_convergence`: GP error over n_train."""
from bayescalib.figures import convergence_figure
from bayescalib.pipeline import setup_logging

setup_logging(snakemake.log[0])  # noqa: F821
convergence_figure(snakemake.input[0], snakemake.params.plots, snakemake.params.stem)  # noqa: F821
