"""Stage ``posterior_check`` (rule ``posterior_check``): the final posterior checked with
real solves by importance sampling.

The forward solves of equally weighted draws of the posterior (rule
``predictive_solve``) each get their discrepancy and real log-likelihood
(:func:`bayescalib.stages.discrepancy.discrepancy`); weighing them against the
surrogate's log-likelihood the SMC sampled tells whether the surrogate's posterior holds
(:func:`bayescalib.inference.active.final_posterior_check`: the importance check and
the mass test of the posterior's separated modes).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.stages.discrepancy import discrepancy
from bayescalib.stages.files import read_stage_file, write_json

__all__ = ["posterior_check"]

log = logging.getLogger("bayescalib")


def posterior_check(sample_runs: Sequence[str | Path], obs_path: str | Path, measure_name: str,
                    measure: Mapping[str, Any], likelihood: Mapping[str, Any],
                    surrogate_path: str | Path, parameters: Sequence[Mapping[str, Any]],
                    check: Mapping[str, Any], out_path: str | Path,
                    particles_path: str | Path) -> dict[str, Any]:
    """The final posterior checked by importance sampling with real solves.

    ``sample_runs`` are the forward solves of equally weighted draws of the final
    posterior (the ``predictive_solve`` jobs, resampled from ``particles_path``); each
    gets its discrepancy and real log-likelihood (records under ``<out>.draws/``), the
    surrogate's log-likelihood at the same parameters is the one the SMC sampled, and
    :func:`bayescalib.inference.active.final_posterior_check` compares the two
    posteriors (and the masses of their separated modes), and asks whether the draws
    represent the weighted particles' mean and sd (a tail the draws missed is not
    checked by them). Writes ``out_path`` (JSON: the
    check's numbers keyed by parameter name, in the user's units) and returns it.
    ``check`` is the ``posterior_check`` section (the rule's param keeps its name).
    """
    from bayescalib.inference.active import final_posterior_check

    names = [p["name"] for p in parameters]
    targets = [p["target"] for p in parameters]
    draws_dir = Path(str(out_path) + ".draws")
    X, L = [], []
    for k, rp in enumerate(sample_runs):
        rec = discrepancy(rp, obs_path, measure_name, measure, likelihood,
                          draws_dir / f"{k}.json")
        X.append([float(rec["parameters"][t]) for t in targets])
        L.append(-math.inf if rec.get("loglik") is None else float(rec["loglik"]))
    X_arr, L_arr = np.asarray(X, float).reshape(-1, len(names)), np.asarray(L, float)
    gp = read_stage_file(surrogate_path, "surrogate")
    mu = gp.predict(X_arr)
    smc = read_stage_file(particles_path, "SMC particle file")
    res = final_posterior_check(X_arr, L_arr, mu, smc.particles, smc.weights, check)
    out = {"measure": measure_name, "names": names, **res,
           "draws": [{"parameters": dict(zip(names, x, strict=True)),
                      "loglik": None if not math.isfinite(ll) else ll,
                      "surrogate_loglik": float(m)}
                     for x, ll, m in zip(X_arr.tolist(), L_arr.tolist(), mu.tolist(),
                                         strict=True)]}
    for key in ("mean_q", "sd_q", "mean_is", "sd_is", "shift_sd", "shift_se", "sd_ratio",
                "draws_shift_sd", "draws_sd_ratio"):
        if key in out:
            out[key] = dict(zip(names, out[key], strict=True))
    write_json(out_path, out)
    log.info("posterior check (%s): %s", measure_name, res["words"])
    return out
