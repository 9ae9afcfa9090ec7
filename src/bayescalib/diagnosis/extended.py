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

__all__ = [
    "CandidateSpec",
    "calibrate_with_points",
    "extended_calibration",
    "extended_parameters",
    "refine_calibration",
    "training_rows",
]

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


def calibrate_with_points(
    *,
    fm: Mapping[str, Any],
    parameters: Sequence[Mapping[str, Any]],
    X_new: np.ndarray,
    switches: Mapping[str, Any],
    reused: Mapping[str, Any],
    obs_path: str | Path,
    measure_name: str,
    measure: Mapping[str, Any],
    likelihood: Mapping[str, Any],
    surrogate: Mapping[str, Any],
    smc_cfg: Mapping[str, Any],
    posterior_cfg: Mapping[str, Any],
    workdir: str | Path,
    workers: int = 1,
    warm_start: str | Path | None = None,
) -> dict[str, Any]:
    """Solve the new points ``X_new``, add them to the ``reused`` training rows and run
    surrogate, SMC and posterior summaries on the union (all files under ``workdir``).

    Parameters
    ----------
    parameters
        Parameter list of the calibrated model (columns of ``X_new``).
    X_new
        New design points, shape (n, d), in the parameters' units.
    switches
        Forward-model settings added to every new point (e.g. a candidate's switch).
    reused
        Training rows kept as they are: ``X`` (m, d), ``loglik``, ``D``, ``status`` (m,)
        and ``reason`` (m strings).

    Returns
    -------
    dict
        ``log_evidence``, ``posterior`` (the summary of
        :func:`bayescalib.posterior.summarize`), ``n_new``, ``n_reused``, ``n_failed``
        and the paths of the ``training``, ``particles`` and ``surrogate`` files.
    """
    from bayescalib.diagnosis.solves import solve_many
    from bayescalib.pipeline import (
        discrepancy,
        marginalize,
        record_bound,
        smc,
        train,
        write_training,
    )
    from bayescalib.posterior import read_particles_h5

    work = Path(workdir)
    targets = [p.get("target") or p["name"] for p in parameters]
    X_new = np.atleast_2d(np.asarray(X_new, dtype=float))
    points = [{**dict(zip(targets, map(float, row), strict=True)), **switches}
              for row in X_new]
    run_paths = [work / "runs" / f"{i}.h5" for i in range(len(points))]
    runs = solve_many(fm, points, run_paths, workers=workers, warm_start=warm_start)
    L = np.full(len(points), -np.inf)
    D = np.full(len(points), np.nan)
    ok = np.zeros(len(points), dtype=np.int8)
    bound = np.full(len(points), np.nan)
    reasons = []
    for i, (run, rp) in enumerate(zip(runs, run_paths, strict=True)):
        rec = discrepancy(rp, obs_path, measure_name, measure, likelihood,
                          work / "discrepancy" / f"{i}.json")
        if run.ok and rec.get("loglik") is not None:
            L[i], D[i], ok[i] = float(rec["loglik"]), float(rec["D"]), 1
            bound[i] = record_bound(rec)
        reasons.append(run.reason or rec.get("reason") or "")
    X = np.vstack([np.asarray(reused["X"], dtype=float), X_new])
    L_all = np.concatenate([reused["loglik"], L])
    D_all = np.concatenate([reused["D"], D])
    ok_all = np.concatenate([np.asarray(reused["status"], dtype=np.int8), ok])
    reasons_all = list(reused["reason"]) + reasons
    names = [p["name"] for p in parameters]
    training = work / "training.h5"
    bound_all = np.concatenate([np.asarray(reused["bound"], float), bound])
    write_training(training, X, L_all, D_all, ok_all, reasons_all, names, len(L_all),
                   bound=bound_all)
    surrogate_path = work / "surrogate.h5"
    particles = work / "particles.h5"
    train(training, surrogate, parameters, surrogate_path)
    smc(surrogate_path, smc_cfg, parameters, particles)
    summary = marginalize(particles, surrogate_path, posterior_cfg, parameters,
                          int(smc_cfg["seed"]), work / "posterior.json", work / "posterior.nc")
    res = read_particles_h5(particles)
    n_failed = int(len(points) - ok.sum())
    log.info("calibration in %s: log evidence %.3f, %d new points (%d failed), %d reused",
             work, res.log_evidence, len(points), n_failed, len(reused["loglik"]))
    return {"parameters": [dict(p) for p in parameters],
            "log_evidence": float(res.log_evidence), "posterior": summary,
            "n_new": len(points), "n_reused": len(reused["loglik"]), "n_failed": n_failed,
            "training": str(training), "particles": str(particles),
            "surrogate": str(surrogate_path)}


def training_rows(training: str | Path) -> dict[str, Any]:
    """The rows of a training table that are used for training."""
    from bayescalib.pipeline import read_training

    tab = read_training(training)
    use = tab["is_train"].astype(bool)
    return {"X": tab["X"][use], "loglik": tab["loglik"][use], "D": tab["D"][use],
            "status": tab["status"][use], "bound": tab["bound"][use],
            "reason": [r for r, u in zip(tab["reason"], use, strict=True) if u]}


def refine_calibration(
    cal: Mapping[str, Any],
    *,
    max_rounds: int,
    n_points: int,
    tol: float,
    seed: int,
    switches: Mapping[str, Any],
    workdir: str | Path,
    **common: Any,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Posterior-targeted refinement rounds (:mod:`bayescalib.refinement`) of a finished
    calibration ``cal`` (a dict with ``parameters``, ``training``, ``particles``,
    ``log_evidence`` and ``posterior``).

    Each round adds ``n_points`` solves where the current posterior lives, refits the
    surrogate and reruns SMC (files under ``workdir/round_<k>``). The rounds stop after
    ``max_rounds``, or as soon as a round moves no posterior mean by more than ``tol``
    posterior standard deviations (the surrogate agrees with the new solves where the
    posterior lives). ``common`` holds the remaining arguments of
    :func:`calibrate_with_points`.

    Returns
    -------
    cal : dict
        The calibration after the last round (``cal`` itself when ``max_rounds`` is 0).
    history : list of dict
        Per round: ``round``, ``n_new``, ``n_failed``, ``log_evidence``, ``mean``,
        ``std`` and ``shift_sd`` (the largest move of a posterior mean in posterior
        standard deviations; round 0 is the calibration given, with its own ``n_new``
        and ``n_failed`` when it has them).
    """
    from bayescalib.parameters import ParameterSpace
    from bayescalib.posterior import read_particles_h5
    from bayescalib.refinement import refinement_points

    def entry(k: int, c: Mapping[str, Any], prev: Mapping[str, Any] | None) -> dict[str, Any]:
        post = c["posterior"]
        mean, std = dict(post["mean"]), dict(post["std"])
        shift = None if prev is None else max(
            abs(mean[n] - prev["mean"][n]) / max(std[n], 1e-12 * max(1.0, abs(mean[n])))
            for n in mean)
        return {"round": k, "n_new": int(c.get("n_new", 0)),
                "n_failed": int(c.get("n_failed", 0)),
                "log_evidence": float(c["log_evidence"]), "mean": mean, "std": std,
                "shift_sd": None if shift is None else float(shift)}

    history = [entry(0, cal, None)]
    rng = np.random.default_rng(int(seed))
    space = ParameterSpace.from_config(cal["parameters"])
    for k in range(1, int(max_rounds) + 1):
        res = read_particles_h5(cal["particles"])
        rows = training_rows(cal["training"])
        X_new = refinement_points(np.asarray(res.particles), np.asarray(res.weights),
                                  int(n_points), space.bounds, rng, design=rows["X"])
        cal = calibrate_with_points(parameters=cal["parameters"], X_new=X_new,
                                    switches=switches, reused=rows,
                                    workdir=Path(workdir) / f"round_{k}", **common)
        history.append(entry(k, cal, history[-1]))
        log.info("refinement round %d: posterior means moved by up to %.2f sd", k,
                 history[-1]["shift_sd"])
        if history[-1]["shift_sd"] <= float(tol):
            break
    return dict(cal), history


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
        As :func:`calibrate_with_points`, plus ``candidate``.
    """
    from bayescalib.design import sobol_design
    from bayescalib.parameters import ParameterSpace

    params_ext = extended_parameters(parameters, cand)
    space = ParameterSpace.from_config(params_ext)
    X_new = sobol_design(space.bounds, int(n_new), int(seed))
    base = training_rows(base_training)
    reused = {**base, "X": np.hstack([base["X"], np.zeros((len(base["loglik"]), 1))])}
    cal = calibrate_with_points(
        fm=fm, parameters=params_ext, X_new=X_new, switches=cand.switches, reused=reused,
        obs_path=obs_path, measure_name=measure_name, measure=measure, likelihood=likelihood,
        surrogate=surrogate, smc_cfg=smc_cfg, posterior_cfg=posterior_cfg, workdir=workdir,
        workers=workers, warm_start=warm_start)
    return {"candidate": cand.name, **cal}
