"""Checkpoint `acquire`: end of an active-design round (checks, stop rule, next batch)."""
from bayescalib.pipeline import acquire, setup_logging

sm = snakemake  # noqa: F821
setup_logging(sm.log[0])
acquire(sm.params.round, sm.input.training, sm.input.surrogate, sm.input.particles,
        sm.input.previous[0] if sm.input.previous else None, sm.params.active,
        sm.params.parameters, sm.output[0])
