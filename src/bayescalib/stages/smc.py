"""Stage ``smc`` (rules ``smc`` and ``smc_round``): sequential Monte Carlo with adaptive
tempering (paper Sec. 3.1, Alg. alg:smc) on the surrogate's log-likelihood, the
particles of the posterior in an HDF5 file.

A surrogate with the same content as an earlier SMC's (the last active round's) reuses
its particles (:func:`bayescalib.stages.files.reuse_output`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bayescalib.stages.files import read_stage_file, reuse_output

__all__ = ["smc"]

log = logging.getLogger("bayescalib")


def smc(surrogate_path: str | Path, smc_cfg: Mapping[str, Any],
        parameters: Sequence[Mapping[str, Any]], out_path: str | Path, *,
        threads: int = 1, reuse: Sequence[str | Path] = ()) -> None:
    """Run SMC with adaptive tempering on the GP mean of the log-likelihood.

    ``threads`` > 1 evaluates the surrogate's chunks of particles on that many threads
    (:attr:`GPSurrogate.threads`): the same chunks, each computed alone, so the
    particles are bitwise those of one thread. ``reuse``: (surrogate, particles) of an
    earlier SMC with the same settings (the last active round's); when the surrogate
    holds the same content, those particles are copied instead of sampled again
    (:func:`bayescalib.stages.files.reuse_output`; their history's ``time_s`` is the
    earlier run's).
    """
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.inference.posterior import write_particles_h5
    from bayescalib.inference.smc import smc_from_config

    if reuse_output(surrogate_path, reuse, out_path, "smc"):
        return
    gp = read_stage_file(surrogate_path, "surrogate")
    gp.threads = max(1, int(threads))
    space = ParameterSpace.from_config(parameters)

    result = smc_from_config(gp.loglik, space, smc_cfg)
    write_particles_h5(out_path, result, space)
    log.info("SMC done: %d steps, log evidence %.4f", result.n_steps, result.log_evidence)
