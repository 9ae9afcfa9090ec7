"""The rounds of a calibration in files, for stages that calibrate inside a job.

The workflow calibrates a study rule by rule: ``solve`` every point of a round,
``discrepancy``, ``gather``, ``train_surrogate``, ``smc``, the ``acquire`` checkpoint
(:func:`bayescalib.inference.rounds.decide`) and, after the last round, ``marginalize``.
The diagnosis must calibrate models that are known only while it runs (the base model
plus one candidate effect), so it cannot be given rules in advance.
:func:`calibrate_rounds` runs the rounds in-process with the one driver
(:func:`bayescalib.inference.rounds.run_rounds`) and two strategies of this module:
:class:`FileStore`, whose steps are the stage functions the rules run, and
:class:`SolvePath`, which evaluates points by the solve path
(:func:`bayescalib.models.forward.solve_points`: one isolated, time-limited solve per
point, a solve process keeping its mesh between points) and their discrepancy. The files of each round are laid out as in the
workflow's results::

    <workdir>/runs/<i>.h5                  run record of new point i
    <workdir>/discrepancy/<i>.json         its discrepancy and log-likelihood
    <workdir>/active/<r>/training.h5       training table of round r (reused rows first)
    <workdir>/active/<r>/surrogate.h5      surrogate of round r
    <workdir>/active/<r>/particles.h5      SMC on it
    <workdir>/active/<r>/acquire.json      trust check, posterior check, stop rule, next batch
    <workdir>/surrogate.h5                 a full search of the surrogate's discrete
                                           choices on the last round's data, when that
                                           round refitted the previous choices
                                           (``surrogate.reselect_growth``)
    <workdir>/particles.h5                 SMC on the final surrogate with the
                                           study's settings, when the rounds used
                                           lighter ones (``design.active.smc``) or it
                                           is the surrogate above
    <workdir>/posterior.json, posterior.nc summaries of the result

Solves are reused when their run record exists with the same values; surrogates, SMC
and the acquisition are recomputed (they are seeded, so a rerun chooses the same
points and solves nothing again).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["FileStore", "SolvePath", "calibrate_rounds", "training_rows"]

log = logging.getLogger(__name__)


def training_rows(training: str | Path):
    """The rows of a training table (:func:`bayescalib.stages.gather.gather`) used for training,
    as :class:`~bayescalib.inference.rounds.Evaluations`."""
    from bayescalib.inference.rounds import Evaluations
    from bayescalib.stages.files import read_stage_file

    tab = read_stage_file(training, "training table")
    return Evaluations.from_rows(tab).take(tab["is_train"].astype(bool))


@dataclass
class SolvePath:
    """Evaluates points by the solve path: run records under ``<workdir>/runs``, their
    discrepancy and log-likelihood under ``<workdir>/discrepancy``, numbered on from
    the points solved before (:class:`~bayescalib.inference.rounds.Evaluator`).

    Attributes
    ----------
    fm : the validated ``forward_model`` section (``loadings`` included).
    parameters : the parameter list (its ``target``s are the points' columns).
    obs_path : the observation store.
    measure_name, measure, likelihood : the measure used and the validated ``measure``
        and ``likelihood`` sections.
    workdir : the folder of the files.
    switches : forward-model settings added to every solve (e.g.
        ``physics.growth.enabled``).
    workers : solves at once.
    warm_start : the base state the solves start from (None: none).
    """

    fm: Mapping[str, Any]
    parameters: Sequence[Mapping[str, Any]]
    obs_path: str | Path
    measure_name: str
    measure: Mapping[str, Any]
    likelihood: Mapping[str, Any]
    workdir: str | Path
    switches: Mapping[str, Any] = field(default_factory=dict)
    workers: int = 1
    warm_start: str | Path | None = None
    run_paths: list[Path] = field(default_factory=list)
    disc_paths: list[Path] = field(default_factory=list)

    def __call__(self, X: np.ndarray):
        from bayescalib.inference.rounds import Evaluations
        from bayescalib.models.forward import solve_points
        from bayescalib.stages.discrepancy import discrepancy
        from bayescalib.stages.gather import gather_rows

        work = Path(self.workdir)
        targets = [p["target"] for p in self.parameters]
        X = np.atleast_2d(np.asarray(X, float))
        i0 = len(self.run_paths)
        points = [{**dict(zip(targets, map(float, row), strict=True)), **self.switches}
                  for row in X]
        runs = [work / "runs" / f"{i0 + k}.h5" for k in range(len(points))]
        discs = [work / "discrepancy" / f"{i0 + k}.json" for k in range(len(points))]
        solve_points(self.fm, points, runs, workers=self.workers, warm_start=self.warm_start)
        for rp, dp in zip(runs, discs, strict=True):
            discrepancy(rp, self.obs_path, self.measure_name, self.measure[self.measure_name],
                        self.likelihood, dp)
        self.run_paths.extend(runs)
        self.disc_paths.extend(discs)
        return Evaluations.from_rows(gather_rows(runs, discs, targets))


@dataclass
class FileStore:
    """The rounds' products in files (the module docstring), each step the stage
    function the workflow's rule runs, its output read back
    (:class:`~bayescalib.inference.rounds.RoundStore`).

    Attributes
    ----------
    workdir : the folder of the files.
    parameters : the parameter list.
    settings : :class:`~bayescalib.inference.rounds.RoundSettings`.
    threads : processes of the surrogate's full searches (the ``threads`` of
        :func:`bayescalib.stages.surrogate.train_surrogate`; the same surrogate as one
        process, bit for bit).
    training, surrogate, particles : the files last written of each kind (after the
        rounds: the result's).
    """

    workdir: str | Path
    parameters: Sequence[Mapping[str, Any]]
    settings: Any
    threads: int = 1
    training: Path | None = None
    surrogate: Path | None = None
    particles: Path | None = None

    def _folder(self, r: int | None) -> Path:
        return Path(self.workdir) if r is None else Path(self.workdir) / "active" / str(r)

    def fit(self, r: int | None, rows, previous: Any) -> Any:
        from bayescalib.io.training import write_training
        from bayescalib.stages.files import read_stage_file
        from bayescalib.stages.surrogate import train_surrogate

        if r is not None:  # the result's surrogate is fitted to the last round's table
            self.training = self._folder(r) / "training.h5"
            write_training(self.training, rows.X, rows.loglik, rows.D, rows.status,
                           list(rows.reason), [p["name"] for p in self.parameters], len(rows),
                           bound=rows.bound, n_measurements=rows.n_measurements,
                           residuals=rows.residuals)
        prev = None if previous is None else self.surrogate
        self.surrogate = self._folder(r) / "surrogate.h5"
        train_surrogate(self.training, self.settings.surrogate, self.parameters,
                        self.surrogate, previous=prev, threads=self.threads)
        return read_stage_file(self.surrogate, "surrogate")

    def sample(self, r: int | None, surrogate: Any, smc: Mapping[str, Any]) -> Any:
        from bayescalib.stages.files import read_stage_file
        from bayescalib.stages.smc import smc as run_smc

        self.particles = self._folder(r) / "particles.h5"
        run_smc(self.surrogate, smc, self.parameters, self.particles)
        return read_stage_file(self.particles, "SMC particle file")

    def decide(self, r: int, rows, surrogate: Any, result: Any,
               previous: Mapping[str, Any] | None) -> dict[str, Any]:
        from bayescalib.stages.acquire import acquire

        rd = self._folder(r)
        return acquire(r, self.training, self.surrogate, self.particles,
                       None if previous is None else self._folder(r - 1) / "acquire.json",
                       self.settings.active, self.settings.posterior_check,
                       self.parameters, rd / "acquire.json")


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
    reused=None,
    workers: int = 1,
    warm_start: str | Path | None = None,
    posterior_check: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Calibrate by active-design rounds in files (see the module docstring).

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
        Evaluations that enter every round as they are
        (:class:`~bayescalib.inference.rounds.Evaluations`, e.g. the base design at
        ``phi = 0``: :func:`training_rows`); None: none.
    posterior_check
        Validated ``posterior_check`` section: the rounds' check rounds
        (:func:`bayescalib.inference.active.acquire_round`). None: none (``draws`` 0),
        and a posterior settled and trusted (the trust check within ``gp_tol``) for
        ``patience`` rounds converges; the diagnosis tests its extended calibrations
        with solves of their draws itself (its predictive check).

    Returns
    -------
    dict
        ``parameters``, ``log_evidence``, ``posterior`` (the summary of
        :func:`bayescalib.inference.posterior.summarize`), ``converged``, ``reason``,
        ``fit``, ``rounds`` (the acquire records), ``n_new``, ``n_reused``,
        ``n_failed`` (of the new solves), the paths ``training``, ``surrogate``,
        ``particles`` of the result (the last round's files, or the result's own full
        search in ``workdir`` when the last round refitted its choices) and ``workdir``
        (round r's files are in ``workdir/active/r``).
    """
    from bayescalib.config import round_smc, validate
    from bayescalib.inference.rounds import RoundSettings, run_rounds
    from bayescalib.stages.marginalize import marginalize

    posterior_check = validate({"posterior_check": dict(posterior_check or {"draws": 0})},
                               "inference", where="calibrate_rounds")["posterior_check"]
    settings = RoundSettings(active, surrogate, smc_cfg, round_smc(smc_cfg, active),
                             posterior_check)
    work = Path(workdir)
    evaluate = SolvePath(fm, parameters, obs_path, measure_name, measure, likelihood, work,
                         dict(switches or {}), workers, warm_start)
    store = FileStore(work, parameters, settings, threads=workers)
    n_reused = 0 if reused is None else len(reused)
    res = run_rounds(evaluate, store, settings, initial, done=reused)
    summary = marginalize(store.particles, store.surrogate, posterior_cfg, parameters,
                          int(smc_cfg["seed"]), work / "posterior.json", work / "posterior.nc")
    n_new = len(res.rows) - n_reused
    n_failed = int(n_new - np.asarray(res.rows.status[n_reused:]).sum())
    log.info("calibration in %s: %d round(s), %d new solves (%d failed), %d reused; %s",
             work, len(res.rounds), n_new, n_failed, n_reused, res.reason)
    return {"parameters": [dict(p) for p in parameters],
            "log_evidence": float(res.smc.log_evidence), "posterior": summary,
            "converged": res.converged, "reason": res.reason, "fit": res.fit,
            "rounds": res.rounds, "n_new": n_new, "n_reused": n_reused, "n_failed": n_failed,
            "training": str(store.training), "surrogate": str(store.surrogate),
            "particles": str(store.particles), "workdir": str(work)}
