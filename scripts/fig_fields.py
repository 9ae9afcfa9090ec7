"""Rule `fig_fields`: ground-truth velocity, pressure and displacement fields."""
from bayescalib.stages import setup_logging
from bayescalib.stages.figures import field_figure

setup_logging(snakemake.log[0])  # noqa: F821
field_figure(snakemake.input.vtu, snakemake.input.run, snakemake.params.plots, snakemake.params.stem)  # noqa: F821
