"""The rounds of a calibration by active design: one driver for every place that runs them.

Round, check round, trust check, posterior check: docs/glossary.md.

A calibration in rounds (what a round decides: :mod:`bayescalib.inference.active`)
repeats, for r = 0, 1, ...:

1. **fit** the surrogate to every evaluation so far (:func:`fit_surrogate`: the GP of
   the log-likelihood of paper Sec. 3.2, eq. prior_gp, its discrete choices searched
   or refitted by :func:`~bayescalib.inference.gp.selection.fit_round`; or, with
   ``surrogate.target: outputs``, the emulator of the residual vectors,
   :mod:`bayescalib.inference.emulator`);
2. **sample** its posterior by SMC with adaptive tempering (paper Algorithm 1), with
   the rounds' settings (:func:`~bayescalib.config.round_smc`);
3. **decide** (:func:`decide`): the trust check, the posterior check of a check round,
   the exploration audit, the stop rule and the next batch
   (:func:`~bayescalib.inference.active.acquire_round`);
4. **evaluate** the batch, unless the round stopped.

After the last round the result's surrogate is a full search of the discrete choices
on all evaluations (the last round's when it was one), and its posterior is sampled
with the study's SMC settings where the rounds used lighter ones.

:func:`run_rounds` is that loop, written once. Two things vary, passed in as
strategies:

* where a round's products live, the *store*: :class:`MemoryStore` keeps them as
  objects (tests, benchmarks, :func:`calibrate`); the file store of
  :mod:`bayescalib.stages.chain` writes each round's training table, surrogate,
  particles and record where the workflow keeps them, through the stage functions
  the Snakemake rules run (the diagnosis's extended calibrations). The workflow's own
  rounds are those rules, its ``acquire`` checkpoint calling :func:`decide`;
* how points are evaluated, the *evaluator*: a Python function of the
  log-likelihood (:class:`LoglikFunction`) or of the residual vector
  (:class:`OutputsFunction`), or the solve path
  (:class:`bayescalib.stages.chain.SolvePath`: one isolated solve per point, its
  discrepancy and log-likelihood).

Each store computes a step with the same functions, and a surrogate or SMC result read
back from its file equals the one written bit for bit, so a problem runs the same
rounds through every store and evaluator (``tests/test_rounds.py``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

__all__ = [
    "Evaluations",
    "LoglikFunction",
    "MemoryStore",
    "OutputsFunction",
    "RoundSettings",
    "RoundStore",
    "RoundsResult",
    "calibrate",
    "calibrate_in_memory",
    "calibrate_outputs",
    "decide",
    "fit_surrogate",
    "run_rounds",
]

log = logging.getLogger(__name__)


# ------------------------------------------------------------------- evaluations
@dataclass(frozen=True)
class Evaluations:
    """The evaluated design points of a calibration, in the order they were evaluated:
    the rows of a training table (:mod:`bayescalib.io.training`).

    Attributes
    ----------
    X : (n, d) points in the parameters' units.
    loglik : (n,) their log-likelihoods; -inf where the evaluation failed.
    status : (n,) 1 evaluated, 0 failed.
    reason : (n,) why an evaluation failed ('' when it did not, or unsaid).
    bound : (n,) the log-likelihood's upper bound at a perfect fit (NaN: unknown).
    n_measurements : (n,) the measurements behind each value (NaN: unknown).
    residuals : (n, m) residual vectors in noise units, loglik = bound - |r|^2 / 2
        (a row of NaN for a failure; m = 0: none recorded).
    D : (n,) the discrepancy of each solve (NaN: none).
    """

    X: np.ndarray
    loglik: np.ndarray
    status: np.ndarray
    reason: tuple[str, ...]
    bound: np.ndarray
    n_measurements: np.ndarray
    residuals: np.ndarray
    D: np.ndarray

    @classmethod
    def empty(cls, d: int) -> Evaluations:
        """No evaluations of a d-parameter problem."""
        z = np.zeros(0)
        return cls(np.zeros((0, d)), z, np.zeros(0, np.int8), (), z, z, np.zeros((0, 0)), z)

    @classmethod
    def from_rows(cls, rows: Mapping[str, Any]) -> Evaluations:
        """From a mapping with the attributes' names as keys (a training table's columns,
        :func:`bayescalib.stages.gather.gather_rows`)."""
        X = np.atleast_2d(np.asarray(rows["X"], float))
        n = X.shape[0]
        R = np.asarray(rows["residuals"], float)
        return cls(X, np.asarray(rows["loglik"], float).reshape(n),
                   np.asarray(rows["status"], np.int8).reshape(n), tuple(map(str, rows["reason"])),
                   np.asarray(rows["bound"], float).reshape(n),
                   np.asarray(rows["n_measurements"], float).reshape(n),
                   R.reshape(n, -1) if R.size else np.zeros((n, 0)),
                   np.asarray(rows["D"], float).reshape(n))

    def __len__(self) -> int:
        return int(self.X.shape[0])

    def take(self, rows: slice | np.ndarray) -> Evaluations:
        """The rows ``rows`` (a slice, an index array or a boolean mask)."""
        idx = np.arange(len(self))[rows]
        return Evaluations(self.X[idx], self.loglik[idx], self.status[idx],
                           tuple(self.reason[i] for i in idx), self.bound[idx],
                           self.n_measurements[idx], self.residuals[idx], self.D[idx])

    def with_columns(self, values: np.ndarray) -> Evaluations:
        """The same evaluations with parameters appended to every point: ``values``
        (k,), e.g. a candidate effect's magnitude at which the rows were solved."""
        v = np.asarray(values, float).reshape(1, -1)
        return replace(self, X=np.hstack([self.X, np.repeat(v, len(self), axis=0)]))

    def __add__(self, other: Evaluations) -> Evaluations:
        """These rows, then ``other``'s. Residual vectors of unequal width (rows without
        any: m = 0) are NaN in the wider one's width."""
        m = max(self.residuals.shape[1], other.residuals.shape[1])
        R = np.vstack([e.residuals if e.residuals.shape[1] == m
                       else np.full((len(e), m), np.nan) for e in (self, other)])
        d = other.X.shape[1] if len(other) else self.X.shape[1]
        return Evaluations(
            np.vstack([self.X.reshape(-1, d), other.X.reshape(-1, d)]),
            np.concatenate([self.loglik, other.loglik]),
            np.concatenate([self.status, other.status]).astype(np.int8),
            self.reason + other.reason,
            np.concatenate([self.bound, other.bound]),
            np.concatenate([self.n_measurements, other.n_measurements]), R,
            np.concatenate([self.D, other.D]))

    def likelihood_bound(self) -> float | None:
        """The largest recorded bound (the log-likelihood of a perfect fit), or None."""
        b = self.bound[np.isfinite(self.bound)]
        return float(b.max()) if b.size else None


class Evaluator(Protocol):
    """Evaluates design points: (q, d) points -> their :class:`Evaluations`."""

    def __call__(self, X: np.ndarray) -> Evaluations: ...


@dataclass(frozen=True)
class LoglikFunction:
    """A log-likelihood given as a vectorized Python function, (q, d) -> (q,), -inf where
    the model fails; ``bound``: its value at a perfect fit (None: unknown),
    ``n_measurements``: the measurements behind it (None: unknown)."""

    loglik: Callable[[np.ndarray], np.ndarray]
    bound: float | None = None
    n_measurements: int | None = None

    def __call__(self, X: np.ndarray) -> Evaluations:
        X = np.atleast_2d(np.asarray(X, float))
        L = np.asarray(self.loglik(X), float).reshape(len(X))
        L = np.where(np.isnan(L), -np.inf, L)
        ok = np.isfinite(L)
        nan = np.full(len(X), np.nan)
        return Evaluations(
            X, L, ok.astype(np.int8), ("",) * len(X),
            np.where(ok, np.nan if self.bound is None else float(self.bound), np.nan),
            np.where(ok, np.nan if self.n_measurements is None else float(self.n_measurements),
                     np.nan),
            np.zeros((len(X), 0)), nan)


@dataclass(frozen=True)
class OutputsFunction:
    """A model given by its outputs in noise units, (q, d) -> (q, m) (a row with NaN: the
    model failed), and the data ``y`` (m,): residual vectors U - y and the Gaussian
    log-likelihood ``offset`` - |U - y|^2 / 2 (``offset``: its value at a perfect fit)."""

    outputs: Callable[[np.ndarray], np.ndarray]
    y: np.ndarray
    offset: float = 0.0

    def __call__(self, X: np.ndarray) -> Evaluations:
        X = np.atleast_2d(np.asarray(X, float))
        R = np.atleast_2d(np.asarray(self.outputs(X), float)) - np.asarray(self.y, float)
        ok = np.all(np.isfinite(R), axis=1)
        R[~ok] = np.nan
        with np.errstate(invalid="ignore"):
            L = np.where(ok, float(self.offset) - 0.5 * np.sum(R ** 2, axis=1), -np.inf)
        m = float(R.shape[1])
        return Evaluations(X, L, ok.astype(np.int8), ("",) * len(X),
                           np.where(ok, float(self.offset), np.nan), np.where(ok, m, np.nan),
                           R, np.where(ok, np.sum(np.nan_to_num(R) ** 2, axis=1), np.nan))


# ------------------------------------------------------------------- the steps
@dataclass(frozen=True)
class RoundSettings:
    """The settings of a calibration in rounds, built once from the validated config.

    Attributes
    ----------
    active : the ``design.active`` section (budget, batches, stop rule, seed).
    surrogate : the ``surrogate`` section.
    smc : the ``smc`` section: the result's sampler.
    round_smc : the rounds' sampler (``smc`` with ``design.active.smc`` applied).
    posterior_check : the ``posterior_check`` section (the check rounds).
    """

    active: Mapping[str, Any]
    surrogate: Mapping[str, Any]
    smc: Mapping[str, Any]
    round_smc: Mapping[str, Any]
    posterior_check: Mapping[str, Any]

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> RoundSettings:
        """From a validated config holding ``design.active``, ``surrogate``, ``smc`` and
        ``posterior_check``."""
        from bayescalib.config import round_smc

        a = cfg["design"]["active"]
        return cls(a, cfg["surrogate"], cfg["smc"], round_smc(cfg["smc"], a),
                   cfg["posterior_check"])

    @classmethod
    def from_sections(cls, *, active: Mapping[str, Any] | None = None,
                      surrogate: Mapping[str, Any] | None = None,
                      smc: Mapping[str, Any] | None = None,
                      posterior_check: Mapping[str, Any] | None = None,
                      where: str = "calibrate") -> RoundSettings:
        """From partial sections, the schema's defaults filling the rest."""
        from bayescalib.config import validate

        return cls.from_config(validate(
            {"design": {"active": dict(active or {})}, "surrogate": dict(surrogate or {}),
             "smc": dict(smc or {}), "posterior_check": dict(posterior_check or {})},
            "inference", where=where))

    @property
    def rounds_lighter(self) -> bool:
        """True when the rounds sample with other settings than the result."""
        return dict(self.round_smc) != dict(self.smc)


def fit_surrogate(rows: Evaluations, surrogate: Mapping[str, Any], bounds: np.ndarray,
                  previous: Any = None, *, threads: int = 1):
    """The surrogate of a round (step 1 of the module docstring).

    ``surrogate.target: loglik``: the GP of the log-likelihood values
    (:func:`~bayescalib.inference.gp.selection.fit_round`), a failure for the machine's sake
    (a time limit, a killed process: :func:`~bayescalib.inference.feasibility.says_nothing_of_the_model`)
    left out as NaN, any other failure kept as -inf (it marks where the model cannot be
    solved, :mod:`bayescalib.inference.feasibility`). ``outputs``: the emulator of the
    residual vectors and the likelihood computed from it. The likelihood's bound is
    the largest recorded one.

    Parameters
    ----------
    rows
        All evaluations so far.
    surrogate
        The validated ``surrogate`` section.
    bounds
        (d, 2) design box.
    previous
        The previous round's surrogate (its discrete choices refitted until the data
        have grown by ``surrogate.reselect_growth`` or it mispredicts the new values by
        more than ``surrogate.reselect_error``); None: a full search.
    threads
        Processes of a full search of the GP's discrete choices (the same surrogate,
        bit for bit: :func:`~bayescalib.inference.gp.selection.fit_from_config`); the
        output emulator is fitted in this process.

    Returns
    -------
    GPSurrogate or EmulatedLikelihood
    """
    from bayescalib.inference.feasibility import fit_targets, marks_infeasible

    bound = rows.likelihood_bound()
    if surrogate["target"] == "outputs":
        from bayescalib.inference.emulator import EmulatedLikelihood, fit_output_emulator

        R = rows.residuals
        opts = surrogate["outputs"]
        marks = marks_infeasible(np.all(np.isfinite(R), axis=1), list(rows.reason))
        em = fit_output_emulator(rows.X, R, bounds, failed=marks,
                                 energy_tol=opts["energy_tol"],
                                 max_components=opts["max_components"], kernel=opts["kernel"],
                                 restarts=surrogate["restarts"], seed=surrogate["seed"],
                                 inputs=surrogate["inputs"], nugget_floor=opts["nugget_floor"])
        return EmulatedLikelihood(em, np.zeros(R.shape[1]), offset=bound)
    from bayescalib.inference.gp.selection import fit_round

    return fit_round(rows.X, fit_targets(rows.loglik, list(rows.reason)), dict(surrogate),
                     bounds, bound=bound, previous=previous, threads=threads)


def decide(r: int, rows: Evaluations, surrogate, result, space, active: Mapping[str, Any],
           posterior_check: Mapping[str, Any],
           previous: Mapping[str, Any] | None) -> dict[str, Any]:
    """The record of round r (step 3 of the module docstring): trust check, posterior
    check (of a check round), stop rule and the next batch
    (:func:`~bayescalib.inference.active.acquire_round`), the batch chosen by the
    surrogate's acquisition when it is the GP of the log-likelihood and made of
    posterior draws when it is the output emulator (its surrogate has no
    variance-driven acquisition), and the surrogate's output transform recorded.

    Parameters
    ----------
    r
        Round index (0: the initial design).
    rows
        All evaluations of rounds 0..r.
    surrogate, result
        The round's surrogate and its SMC result.
    space
        :class:`~bayescalib.inference.parameters.ParameterSpace`.
    active, posterior_check
        The validated ``design.active`` and ``posterior_check`` sections.
    previous
        The record of round r-1 (None in round 0).
    """
    from bayescalib.inference.active import acquire_round
    from bayescalib.inference.emulator import EmulatedLikelihood

    rec = acquire_round(int(r), rows.X, rows.loglik, surrogate, result.particles,
                        result.weights, result.log_evidence, space, active, previous,
                        posterior_check,
                        acquisition="draws" if isinstance(surrogate, EmulatedLikelihood)
                        else "select")
    rec["surrogate_output"] = surrogate.hyperparameters["output"]
    return rec


# ------------------------------------------------------------------- stores
class RoundStore(Protocol):
    """Where the products of the rounds live and how each step is computed.

    ``r`` is the round's index, None for the result's surrogate and sampler after the
    last round."""

    def fit(self, r: int | None, rows: Evaluations, previous: Any) -> Any: ...

    def sample(self, r: int | None, surrogate: Any, smc: Mapping[str, Any]) -> Any: ...

    def decide(self, r: int, rows: Evaluations, surrogate: Any, result: Any,
               previous: Mapping[str, Any] | None) -> dict[str, Any]: ...


@dataclass
class MemoryStore:
    """The rounds' products as objects in this process; ``threads``: the processes of
    the surrogate's full searches (:func:`fit_surrogate`)."""

    space: Any
    settings: RoundSettings
    threads: int = 1

    def fit(self, r: int | None, rows: Evaluations, previous: Any) -> Any:
        return fit_surrogate(rows, self.settings.surrogate, self.space.bounds, previous,
                             threads=self.threads)

    def sample(self, r: int | None, surrogate: Any, smc: Mapping[str, Any]) -> Any:
        from bayescalib.inference.smc import smc_from_config

        return smc_from_config(surrogate.loglik, self.space, smc)

    def decide(self, r: int, rows: Evaluations, surrogate: Any, result: Any,
               previous: Mapping[str, Any] | None) -> dict[str, Any]:
        return decide(r, rows, surrogate, result, self.space, self.settings.active,
                      self.settings.posterior_check, previous)


# ------------------------------------------------------------------- the driver
@dataclass
class RoundsResult:
    """Outcome of :func:`run_rounds`.

    Attributes
    ----------
    rows : every evaluation (:class:`Evaluations`), those given as done first.
    surrogate : the surrogate of all evaluations: the last round's when that round
        searched the discrete choices in full, else a full search fitted after it.
    smc : the SMC result on it (:class:`~bayescalib.inference.smc.SMCResult`), with the
        result's settings.
    rounds : the per-round records (:func:`decide`).
    fit : :func:`bayescalib.inference.likelihood.fit_check` of the best evaluation
        (None where the bound or the number of measurements is unknown).
    """

    rows: Evaluations
    surrogate: Any
    smc: Any
    rounds: list[dict[str, Any]] = field(default_factory=list)
    fit: dict[str, Any] | None = None

    @property
    def X(self) -> np.ndarray:
        """(n, d) every evaluated point."""
        return self.rows.X

    @property
    def loglik(self) -> np.ndarray:
        """(n,) their log-likelihoods (-inf: failed)."""
        return self.rows.loglik

    @property
    def posterior_check(self) -> dict[str, Any] | None:
        """The last posterior check of the rounds (real evaluations of a round's
        posterior draws, which are design points of the next round, in ``X``), or None
        when no check round was run."""
        for rec in reversed(self.rounds):
            if rec.get("posterior_check") is not None:
                return rec["posterior_check"]
        return None

    @property
    def n_evaluations(self) -> int:
        return len(self.rows)

    @property
    def n_rounds(self) -> int:
        return len(self.rounds)

    @property
    def converged(self) -> bool:
        return bool(self.rounds[-1]["converged"])

    @property
    def reason(self) -> str:
        return str(self.rounds[-1]["reason"])


def run_rounds(evaluate: Evaluator, store: RoundStore, settings: RoundSettings,
               initial: np.ndarray, *, done: Evaluations | None = None,
               callback: Callable[[dict[str, Any]], None] | None = None) -> RoundsResult:
    """Calibrate in rounds until the stop rule holds (the module docstring).

    Parameters
    ----------
    evaluate
        The evaluator (:class:`Evaluator`).
    store
        The store (:class:`RoundStore`).
    settings
        :class:`RoundSettings`.
    initial
        (n0, d) the points of round 0.
    done
        Evaluations that enter every round as they are, before the new ones (e.g. the
        base design of a diagnosis, at the candidate effect's zero). The budget
        ``design.active.max_solves`` counts them.
    callback
        Called with each round's record.
    """
    rows = evaluate(np.atleast_2d(np.asarray(initial, float)))
    if done is not None:
        rows = done + rows
    records: list[dict[str, Any]] = []
    previous: dict[str, Any] | None = None
    surrogate: Any = None
    r = 0
    while True:
        surrogate = store.fit(r, rows, surrogate)
        result = store.sample(r, surrogate, settings.round_smc)
        rec = store.decide(r, rows, surrogate, result, previous)
        records.append(rec)
        if callback is not None:
            callback(rec)
        log.info("round %d: %d evaluations; %s", r, rec["n_solves"], rec["reason"])
        if rec["stop"]:
            break
        rows = rows + evaluate(np.asarray(rec["next"]["points"], float))
        previous, r = rec, r + 1
    if getattr(surrogate, "selection", "search") != "search":
        surrogate = store.fit(None, rows, None)  # the result: a full search on all data
        result = store.sample(None, surrogate, settings.smc)
    elif settings.rounds_lighter:
        result = store.sample(None, surrogate, settings.smc)
    from bayescalib.inference.likelihood import fit_check

    return RoundsResult(rows, surrogate, result, records,
                        fit_check(rows.loglik, rows.bound, rows.n_measurements))


# ------------------------------------------------------------------- in memory
def calibrate_in_memory(evaluate: Evaluator, space, settings: RoundSettings, *, seed: int = 0,
                        callback: Callable[[dict[str, Any]], None] | None = None,
                        threads: int = 1) -> RoundsResult:
    """:func:`run_rounds` in memory (:class:`MemoryStore`, its full searches on
    ``threads`` processes), round 0 a scrambled Sobol design of
    ``design.active.n_initial`` points over the box (seed ``seed``)."""
    from bayescalib.inference.design import sobol_design

    initial = sobol_design(space.bounds, int(settings.active["n_initial"]), seed)
    return run_rounds(evaluate, MemoryStore(space, settings, threads), settings, initial,
                      callback=callback)


def calibrate(loglik: Callable[[np.ndarray], np.ndarray], space, *, bound: float | None = None,
              active: Mapping[str, Any] | None = None,
              surrogate: Mapping[str, Any] | None = None,
              smc: Mapping[str, Any] | None = None, seed: int = 0,
              callback: Callable[[dict[str, Any]], None] | None = None,
              n_measurements: int | None = None,
              posterior_check: Mapping[str, Any] | None = None,
              threads: int = 1) -> RoundsResult:
    """Calibrate a log-likelihood given as a Python function, in rounds in memory
    (:func:`calibrate_in_memory` with :class:`LoglikFunction`).

    Parameters
    ----------
    loglik
        Vectorized log-likelihood: (q, d) points -> (q,) values (-inf: failed).
    space
        :class:`~bayescalib.inference.parameters.ParameterSpace` (prior and design box).
    bound
        Known upper bound of the log-likelihood (log-misfit warping); None: none.
    active, surrogate, smc, posterior_check
        Partial ``design.active``, ``surrogate``, ``smc`` and ``posterior_check``
        sections; the schema's defaults fill the rest.
    seed
        Seed of the Sobol design of round 0.
    callback
        Called with each round's record.
    n_measurements
        Number of measurements behind the Gaussian log-likelihood: with ``bound``, the
        result's ``fit`` checks the best evaluation against the noise model.
    threads
        Processes of the surrogate's full searches (the same surrogates, bit for bit:
        :func:`~bayescalib.inference.gp.selection.fit_from_config`).
    """
    settings = RoundSettings.from_sections(active=active, surrogate=surrogate, smc=smc,
                                           posterior_check=posterior_check)
    return calibrate_in_memory(LoglikFunction(loglik, bound, n_measurements), space, settings,
                               seed=seed, callback=callback, threads=threads)


def calibrate_outputs(outputs: Callable[[np.ndarray], np.ndarray], y: Sequence[float], space, *,
                      offset: float = 0.0, active: Mapping[str, Any] | None = None,
                      surrogate: Mapping[str, Any] | None = None,
                      smc: Mapping[str, Any] | None = None,
                      posterior_check: Mapping[str, Any] | None = None, seed: int = 0,
                      callback: Callable[[dict[str, Any]], None] | None = None) -> RoundsResult:
    """Calibrate a model given by its outputs in noise units with the output emulator
    (``surrogate.target: outputs``), in rounds in memory (:func:`calibrate_in_memory`
    with :class:`OutputsFunction`): every batch is made of posterior draws, each the
    check of the posterior that drew it (:func:`decide`).

    Parameters
    ----------
    outputs
        The model: (q, d) points -> (q, m) outputs in noise units (a row with NaN:
        failed).
    y
        (m,) data in noise units.
    space
        :class:`~bayescalib.inference.parameters.ParameterSpace`.
    offset
        The log-likelihood's value at a perfect fit.
    active, surrogate, smc, posterior_check, seed, callback
        As :func:`calibrate`; ``surrogate.target`` is ``outputs``.
    """
    settings = RoundSettings.from_sections(
        active=active, surrogate={**dict(surrogate or {}), "target": "outputs"}, smc=smc,
        posterior_check=posterior_check, where="calibrate_outputs")
    return calibrate_in_memory(OutputsFunction(outputs, np.asarray(y, float), offset), space,
                               settings, seed=seed, callback=callback)
