"""Rule `fig_rounds`: the active design's rounds."""
from bayescalib.figures import rounds_figure
from bayescalib.pipeline import setup_logging

sm = snakemake  # noqa: F821
setup_logging(sm.log[0])
rounds_figure(sm.input.records, sm.input.particles, sm.input.training, sm.params.parameters,
              sm.params.active, sm.params.plots, sm.params.stem)
