"""The active-design calibration chain in one process, for stages that calibrate inside
a job.

The workflow calibrates a study rule by rule: ``solve`` every point of a round,
``discrepancy``, ``gather``, ``train_surrogate``, ``smc``, the ``acquire`` checkpoint (trust
check, stop rule and next batch, :func:`bayescalib.inference.active.acquire_round`), and, after
the last round, ``marginalize``. The diagnosis must calibrate models that are known
only while it runs (the base model plus one candidate effect), so it cannot be given
rules in advance. :func:`calibrate_rounds` runs that same chain in-process: the same
stage functions of :mod:`bayescalib.stages`, the same solve path
(:func:`bayescalib.models.forward.solve_points`, one isolated and time-limited
:func:`~bayescalib.models.forward.solve_point` per point), the same acquisition and stop
rule, and the files of each round laid out as in the workflow's results::

    <workdir>/runs/<i>.h5                  run record of new point i
    <workdir>/discrepancy/<i>.json         its discrepancy and log-likelihood
    <workdir>/active/<r>/training.h5       training table of round r (reused rows first)
    <workdir>/active/<r>/surrogate.h5      GP surrogate of round r
    <workdir>/active/<r>/particles.h5      SMC on it
    <workdir>/active/<r>/acquire.json      checks, stop rule and the batch of round r+1
    <workdir>/surrogate.h5                 a full search of the surrogate's discrete
                                           choices on the last round's data, when that
                                           round refitted the previous choices
                                           (``surrogate.reselect_growth``)
    <workdir>/particles.h5                 SMC on the final surrogate with the
                                           study's settings, when the rounds used
                                           lighter ones (``design.active.smc``) or it
                                           is the surrogate above
    <workdir>/posterior.json, posterior.nc summaries of the last round

Solves are reused when their run record exists with the same values; surrogates, SMC
and the acquisition are recomputed (they are seeded, so a rerun chooses the same
points and solves nothing again).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["calibrate_rounds", "training_rows"]

log = logging.getLogger(__name__)

_ROW_KEYS = ("X", "loglik", "D", "status", "bound", "n_measurements")


def training_rows(training: str | Path) -> dict[str, Any]:
    """The rows of a training table (:func:`bayescalib.stages.gather`) used for training:
    ``X (m, d)``, ``loglik``, ``D``, ``status``, ``bound``, ``n_measurements`` (m,) and
    ``reason`` (m strings)."""
    from bayescalib.stages import read_stage_file

    tab = read_stage_file(training, "training table")
    use = tab["is_train"].astype(bool)
    return {**{k: tab[k][use] for k in _ROW_KEYS}, "residuals": tab["residuals"][use],
            "reason": [r for r, u in zip(tab["reason"], use, strict=True) if u]}


def _stack(a: Mapping[str, Any], b: Mapping[str, Any]) -> dict[str, Any]:
    out = {k: np.concatenate([np.asarray(a[k]), np.asarray(b[k])]) for k in _ROW_KEYS if k != "X"}
    out["X"] = np.vstack([np.asarray(a["X"], float).reshape(-1, np.shape(b["X"])[1]),
                          np.asarray(b["X"], float)])
    out["reason"] = list(a["reason"]) + list(b["reason"])
    # residual vectors: rows without any (m = 0, e.g. reused rows of an older table) are
    # NaN in the other's width
    Ra, Rb = (np.asarray(x["residuals"], float) for x in (a, b))
    m = max(Ra.shape[1], Rb.shape[1])
    out["residuals"] = np.vstack([R if R.shape[1] == m else np.full((len(R), m), np.nan)
                                  for R in (Ra, Rb)])
    return out


def calibrate_rounds(
    *,
    fm: Mapping[str, Any],
    parameters: Sequence[Mapping[str, Any]],
    initial: np.ndarray,
    obs_path: str | Path,
    measure_name: str,
    measure: Mapping[str, Any],
    likelihood: Mapping[str, Any],
    surrogate: Mapping[str, Any],
    smc_cfg: Mapping[str, Any],
    posterior_cfg: Mapping[str, Any],
    active: Mapping[str, Any],
    workdir: str | Path,
    switches: Mapping[str, Any] | None = None,
    reused: Mapping[str, Any] | None = None,
    workers: int = 1,
    warm_start: str | Path | None = None,
    check: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Calibrate by active-design rounds (see the module docstring).

    Parameters
    ----------
    fm
        Validated ``forward_model`` section (``loadings`` included).
    parameters
        Parameter list of the calibrated model (columns of the design).
    initial
        Points solved in round 0, shape (n0, d), in the parameters' units.
    active
        Validated ``design.active`` section. ``max_solves`` counts the reused rows too.
    switches
        Forward-model settings added to every solve (e.g. ``physics.growth.enabled``).
    workers
        Processes of the solves, and of the surrogate's full searches once a round's
        solves are done (the same surrogate as one process, bit for bit).
    reused
        Training rows that enter every round as they are (:func:`training_rows`, with
        ``X`` of shape (m, d)); e.g. the base design at ``phi = 0``.
    check
        Validated ``posterior_check`` section: the rounds' check rounds
        (:func:`bayescalib.inference.active.acquire_round`). None: none (``draws`` 0),
        and a posterior settled and trusted (the trust check within ``gp_tol``) for
        ``patience`` rounds converges; the diagnosis checks its extended calibrations
        with solves of their draws itself.

    Returns
    -------
    dict
        ``parameters``, ``log_evidence``, ``posterior`` (the summary of
        :func:`bayescalib.inference.posterior.summarize`), ``converged``, ``reason``,
        ``rounds`` (the acquire records), ``n_new``, ``n_reused``, ``n_failed`` (of the
        new solves) and the paths ``training``, ``surrogate``, ``particles``.
    """
    from bayescalib.config import round_smc, validate
    from bayescalib.io.training import write_training
    from bayescalib.models.forward import solve_points
    from bayescalib.stages import (
        _full_search,
        acquire,
        discrepancy,
        gather_rows,
        marginalize,
        read_stage_file,
        smc,
        train_surrogate,
    )

    check_cfg = validate({"posterior_check": dict(check or {"draws": 0})}, "inference",
                         where="calibrate_rounds")["posterior_check"]
    work = Path(workdir)
    switches = dict(switches or {})
    targets = [p["target"] for p in parameters]
    names = [p["name"] for p in parameters]
    d = len(names)
    base = dict(reused) if reused is not None else {
        **{k: np.zeros(0) for k in _ROW_KEYS}, "X": np.zeros((0, d)), "reason": [],
        "residuals": np.zeros((0, 0))}
    n_reused = len(base["loglik"])
    run_paths: list[Path] = []
    disc_paths: list[Path] = []

    def solve(X_new: np.ndarray) -> None:
        i0 = len(run_paths)
        X_new = np.atleast_2d(np.asarray(X_new, float))
        points = [{**dict(zip(targets, map(float, row), strict=True)), **switches}
                  for row in X_new]
        runs = [work / "runs" / f"{i0 + k}.h5" for k in range(len(points))]
        discs = [work / "discrepancy" / f"{i0 + k}.json" for k in range(len(points))]
        solve_points(fm, points, runs, workers=workers, warm_start=warm_start)
        for rp, dp in zip(runs, discs, strict=True):
            discrepancy(rp, obs_path, measure_name, measure[measure_name], likelihood, dp)
        run_paths.extend(runs)
        disc_paths.extend(discs)

    solve(initial)
    previous: Path | None = None
    rounds: list[dict[str, Any]] = []
    r = 0
    while True:
        rd = work / "active" / str(r)
        rows = _stack(base, gather_rows(run_paths, disc_paths, targets))
        training = rd / "training.h5"
        write_training(training, rows["X"], rows["loglik"], rows["D"], rows["status"],
                       rows["reason"], names, len(rows["loglik"]), bound=rows["bound"],
                       n_measurements=rows["n_measurements"], residuals=rows["residuals"])
        train_surrogate(training, surrogate, parameters, rd / "surrogate.h5",
                        previous=None if r == 0 else work / "active" / str(r - 1) / "surrogate.h5",
                        threads=workers)  # the round's solves are done: the search's
        smc(rd / "surrogate.h5", round_smc(smc_cfg, active), parameters, rd / "particles.h5")
        rec = acquire(r, training, rd / "surrogate.h5", rd / "particles.h5", previous, active,
                      check_cfg, parameters, rd / "acquire.json")
        rounds.append(rec)
        if rec["stop"]:
            break
        solve(np.asarray(rec["next"]["points"], float))
        previous = rd / "acquire.json"
        r += 1
    particles, final = rd / "particles.h5", rd / "surrogate.h5"
    if not _full_search(final):  # the last round refitted its choices: the result searches them
        final = work / "surrogate.h5"
        train_surrogate(training, surrogate, parameters, final, threads=workers)
        particles = work / "particles.h5"
        smc(final, smc_cfg, parameters, particles)
    elif round_smc(smc_cfg, active) != dict(smc_cfg):  # the rounds sampled lighter
        particles = work / "particles.h5"
        smc(final, smc_cfg, parameters, particles)
    summary = marginalize(particles, final, posterior_cfg, parameters,
                          int(smc_cfg["seed"]), work / "posterior.json", work / "posterior.nc")
    res = read_stage_file(particles, "SMC particle file")
    n_new = len(run_paths)
    n_failed = int(n_new - np.asarray(rows["status"][n_reused:]).sum())
    log.info("calibration in %s: %d round(s), %d new solves (%d failed), %d reused; %s",
             work, len(rounds), n_new, n_failed, n_reused, rec["reason"])
    from bayescalib.inference.likelihood import fit_check

    return {"parameters": [dict(p) for p in parameters],
            "log_evidence": float(res.log_evidence), "posterior": summary,
            "converged": bool(rec["converged"]), "reason": str(rec["reason"]),
            "fit": fit_check(rows["loglik"], rows["bound"], rows["n_measurements"]),
            "rounds": rounds, "n_new": n_new, "n_reused": n_reused, "n_failed": n_failed,
            "training": str(training), "surrogate": str(final),
            "particles": str(particles)}
