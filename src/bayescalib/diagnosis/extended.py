"""Calibration of the extended model "base + one candidate" (step 4 of the diagnosis).

The extended parameter vector is ``(x, theta, phi)``: the study's parameters plus the
candidate's ``phi`` with a uniform prior on its range. Because the candidate is nested
(``phi = 0`` is the base model exactly), every base design point is a valid training
point of the extended model at ``phi = 0``: the base training table is reused as is,
and only ``n_new`` new scrambled Sobol points over the extended box are solved. Then
the usual chain runs on the extended training table: GP surrogate of the
log-likelihood (:func:`bayescalib.pipeline.train`), SMC with adaptive tempering
(:func:`bayescalib.pipeline.smc`, which also estimates the log-evidence) and the
posterior summaries (:func:`bayescalib.pipeline.marginalize`).

The log Bayes factor of the extended against the base model is the difference of the
two SMC log-evidence estimates (paper Sec. 2.3; both on GP surrogates of the same
log-likelihood, so their surrogate errors partly cancel). On the scale of Kass and
Raftery, ``ln B > 1.1`` (B > 3) is positive and ``ln B > 3`` (B > 20) strong evidence.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["CandidateSpec", "extended_calibration", "extended_parameters"]

log = logging.getLogger(__name__)


@dataclass
class CandidateSpec:
    """A candidate effect as the diagnosis uses it.

    Attributes
    ----------
    name
        Name (``physics.<name>`` for the built-in FSI candidates).
    target
        Forward-model key of ``phi``.
    step
        Finite-difference step of ``phi`` for the signature.
    prior
        ``(lo, hi)`` of the uniform prior of ``phi`` in the extended calibration.
    unit
        Unit of ``phi``.
    switches
        Extra forward-model settings that switch the candidate on (e.g.
        ``{"physics.growth.enabled": True}``).
    summary
        Plain-words description.
    """

    name: str
    target: str
    step: float
    prior: tuple[float, float]
    unit: str = "-"
    switches: dict[str, Any] = field(default_factory=dict)
    summary: str = ""


def extended_parameters(parameters: Sequence[Mapping[str, Any]],
                        cand: CandidateSpec) -> list[dict[str, Any]]:
    """The study's parameter list plus ``phi`` of ``cand`` (uniform prior on its range)."""
    lo, hi = (float(v) for v in cand.prior)
    out = [copy.deepcopy(dict(p)) for p in parameters]
    out.append({"name": f"phi_{cand.name}", "unit": cand.unit, "target": cand.target,
                "prior": {"type": "uniform", "lo": lo, "hi": hi}, "bounds": [lo, hi]})
    return out


def extended_calibration(
    cand: CandidateSpec,
    *,
    fm: Mapping[str, Any],
    parameters: Sequence[Mapping[str, Any]],
    base_training: str | Path,
    obs_path: str | Path,
    measure_name: str,
    measure: Mapping[str, Any],
    likelihood: Mapping[str, Any],
    surrogate: Mapping[str, Any],
    smc_cfg: Mapping[str, Any],
    posterior_cfg: Mapping[str, Any],
    n_new: int,
    seed: int,
    workdir: str | Path,
    workers: int = 1,
    warm_start: str | Path | None = None,
) -> dict[str, Any]:
    """Calibrate base + ``cand`` (see the module docstring).

    Returns
    -------
    dict
        ``parameters`` (extended list), ``log_evidence``, ``posterior`` (the summary of
        :func:`bayescalib.posterior.summarize`), ``n_new``, ``n_reused``, ``n_failed``
        and the paths of the ``particles`` and ``surrogate`` files.
    """
    from bayescalib.design import sobol_design
    from bayescalib.diagnosis.solves import solve_many
    from bayescalib.parameters import ParameterSpace
    from bayescalib.pipeline import (
        discrepancy,
        marginalize,
        read_training,
        smc,
        train,
        write_training,
    )
    from bayescalib.posterior import read_particles_h5

    work = Path(workdir)
    params_ext = extended_parameters(parameters, cand)
    space = ParameterSpace.from_config(params_ext)
    targets = [p.get("target") or p["name"] for p in params_ext]
    X_new = sobol_design(space.bounds, int(n_new), int(seed))
    points = [{**dict(zip(targets, map(float, row), strict=True)), **cand.switches}
              for row in X_new]
    run_paths = [work / "runs" / f"{i}.h5" for i in range(len(points))]
    runs = solve_many(fm, points, run_paths, workers=workers, warm_start=warm_start)
    L = np.full(len(points), -np.inf)
    D = np.full(len(points), np.nan)
    ok = np.zeros(len(points), dtype=np.int8)
    reasons = []
    for i, (run, rp) in enumerate(zip(runs, run_paths, strict=True)):
        rec = discrepancy(rp, obs_path, measure_name, measure, likelihood,
                          work / "discrepancy" / f"{i}.json")
        if run.ok and rec.get("loglik") is not None:
            L[i], D[i], ok[i] = float(rec["loglik"]), float(rec["D"]), 1
        reasons.append(run.reason or rec.get("reason") or "")
    base = read_training(base_training)
    use = base["is_train"].astype(bool)
    phi0 = np.zeros((int(use.sum()), 1))
    X = np.vstack([np.hstack([base["X"][use], phi0]), X_new])
    L_all = np.concatenate([base["loglik"][use], L])
    D_all = np.concatenate([base["D"][use], D])
    ok_all = np.concatenate([base["status"][use], ok])
    reasons_all = [r for r, u in zip(base["reason"], use, strict=True) if u] + reasons
    names = [p["name"] for p in params_ext]
    training = work / "training.h5"
    write_training(training, X, L_all, D_all, ok_all, reasons_all, names, len(L_all))
    surrogate_path = work / "surrogate.h5"
    particles = work / "particles.h5"
    train(training, surrogate, params_ext, surrogate_path)
    smc(surrogate_path, smc_cfg, params_ext, particles)
    summary = marginalize(particles, surrogate_path, posterior_cfg, params_ext,
                          int(smc_cfg["seed"]), work / "posterior.json", work / "posterior.nc")
    res = read_particles_h5(particles)
    log.info("extended model %s: log evidence %.3f, %d new points (%d failed), %d reused",
             cand.name, res.log_evidence, len(points), int(len(points) - ok.sum()),
             int(use.sum()))
    return {"candidate": cand.name, "parameters": params_ext,
            "log_evidence": float(res.log_evidence), "posterior": summary,
            "n_new": len(points), "n_reused": int(use.sum()),
            "n_failed": int(len(points) - ok.sum()),
            "particles": str(particles), "surrogate": str(surrogate_path)}
