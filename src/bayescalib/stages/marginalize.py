"""Stage ``marginalize`` (rule ``marginalize``): the posterior's summaries (JSON: mean,
covariance, MAP, credible intervals, the Laplace approximation) and its ArviZ NetCDF
export, from the SMC particles and the surrogate.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.stages.files import read_stage_file, write_json

__all__ = ["marginalize"]


def marginalize(particles_path: str | Path, surrogate_path: str | Path,
                posterior_cfg: Mapping[str, Any], parameters: Sequence[Mapping[str, Any]],
                seed: int, out_json: str | Path, out_netcdf: str | Path) -> dict[str, Any]:
    """Posterior summaries (JSON) and the ArviZ NetCDF export."""
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.inference.posterior import summarize, write_netcdf

    gp = read_stage_file(surrogate_path, "surrogate")
    space = ParameterSpace.from_config(parameters)
    result = read_stage_file(particles_path, "SMC particle file")
    summary = summarize(result, space, loglik=gp.loglik,
                        map_bins=posterior_cfg.get("map_bins"),
                        levels=tuple(posterior_cfg["levels"]))
    write_json(out_json, summary)
    write_netcdf(out_netcdf, result, space, np.random.default_rng(seed),
                 posterior_cfg["n_draws"])
    return summary
