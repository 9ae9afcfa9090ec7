"""Rule `fig_rounds`: the active design's rounds."""
from bayescalib.stages import setup_logging
from bayescalib.stages.figures import rounds_figure

sm = snakemake  # noqa: F821
setup_logging(sm.log[0])
rounds_figure(sm.input.records, sm.input.particles, sm.input.training, sm.params.parameters,
              sm.params.active, sm.params.plots, sm.params.stem)
