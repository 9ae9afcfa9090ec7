"""Rule `fig_convergence`: GP error over n_train."""
from bayescalib.stages import setup_logging
from bayescalib.stages.figures import convergence_figure

setup_logging(snakemake.log[0])  # noqa: F821
convergence_figure(snakemake.input[0], snakemake.params.plots, snakemake.params.stem)  # noqa: F821
