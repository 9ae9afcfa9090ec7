"""Rules `gather` and `gather_round`: a training table (one measure)."""
from bayescalib.stages import gather, setup_logging

sm = snakemake  # noqa: F821
setup_logging(sm.log[0])
gather(sm.input.runs, sm.input.disc, sm.params.names, sm.params.targets, sm.params.n_train,
       sm.output[0])
