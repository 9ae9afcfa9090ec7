"""Up-front estimates of the wall time of a study's GP fits and SMC runs, and the
limits a study must stay within when it is read (:class:`bayescalib.study.Study`).

A setting such as ``surrogate.restarts: 1000000`` or ``smc.n_rej: 10000000`` is valid
by the schema and would run until killed; the estimates below refuse it when the study
is read, naming the key, as ``smc.max_memory_gib`` does for memory. They are
deliberately rough (the time of one optimizer start or one Metropolis-Hastings sweep
depends on the data) and err on the long side; the limits are generous: every study
shipped in ``config/``, ``examples/`` and ``tests/data/`` is estimated well inside them.

Cost model (seconds on one core of the project's 2-core machine):

* **GP fit** (:func:`gp_fit_seconds`): a full search of the surrogate's discrete
  choices fits :func:`bayescalib.inference.gp.selection.search_size` candidate models,
  each from ``restarts`` optimizer starts; one start costs
  ``(GP_START_S + GP_CUBIC_S n^3) p / 9`` for ``n`` training points and ``p``
  hyperparameters (``d + 2`` with one length scale per input, else 3; the constants
  are measured at ``p = 9``, 7-D), five times that with the quadratic mean. The output
  emulator (``surrogate.target: outputs``) fits one GP per principal direction
  (at most ``surrogate.outputs.max_components``, plus one for the input-scale choice).
* **Active design** (:func:`design_sizes`): round 0 fits on ``n_initial`` points and
  every round adds ``batch_size + check_points``, up to ``max_solves``; each round
  searches in full (or refits the previous choice, ``surrogate.reselect_growth``), and
  the final surrogate is a full search on all of them.
* **SMC** (:func:`smc_step_seconds`): one tempering step is ``n_rej`` sweeps of
  ``SMC_SWEEP_S + n_particles (SMC_PARTICLE_S + SMC_KERNEL_S n d)`` (the output emulator:
  its GPs' means and variances, ``SMC_VARIANCE_S n^2`` each). The number of steps is
  not known before the run (it grows with how much the data say), so the limit is on
  one step; the run time quoted beside it takes :data:`SMC_CYCLES` resampling cycles of
  ``ln(ess_min_ratio) / ln(zeta)`` steps (:func:`tempering_steps`), at most ``max_steps``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "GP_CUBIC_S",
    "GP_START_S",
    "MAX_DESIGN_POINTS",
    "MAX_GP_HOURS",
    "MAX_SMC_STEP_MINUTES",
    "SMC_CYCLES",
    "SMC_KERNEL_S",
    "SMC_PARTICLE_S",
    "SMC_SWEEP_S",
    "SMC_VARIANCE_S",
    "Estimate",
    "design_sizes",
    "duration",
    "gp_fit_seconds",
    "smc_step_seconds",
    "study_gp_seconds",
    "study_smc_steps",
    "tempering_steps",
]

#: seconds of one optimizer start of one GP fit apart from its n^3 part (GPy's overhead
#: per start; measured 0.02 s in 2-D with a handful of points)
GP_START_S = 0.05
#: seconds per n^3 (n training points) of one optimizer start at 9 hyperparameters (7-D,
#: one length scale per input): the Cholesky factorisations and gradients of a few hundred
#: evaluations of the evidence. Measured: 1200 s for one start on 2040 points on a quiet
#: core (config/heterogeneous_fixed.yaml), 11-17 s at 380 points (the heterogeneous
#: study's rounds, surrogate.reselect_growth); smooth 2-D test functions about 20 times less
GP_CUBIC_S = 2.0e-7
#: seconds of one Metropolis-Hastings sweep apart from its particles (one vectorized
#: proposal, prior and surrogate call; measured 1.3e-4 s for 200 particles on 8 points)
SMC_SWEEP_S = 1.0e-4
#: seconds per particle of one sweep apart from the surrogate's kernel row
SMC_PARTICLE_S = 1.0e-7
#: seconds per particle, training point and parameter of one sweep (the kernel row of
#: the surrogate's mean; measured 0.6 us per particle on 128 points and 2.1 us on 512 in 2-D)
SMC_KERNEL_S = 2.0e-9
#: seconds per particle and squared training point of one sweep on the output emulator
#: (each coordinate GP's predictive variance; measured 21 us per particle on 493 points)
SMC_VARIANCE_S = 1.0e-10
#: resampling cycles of one tempering run, for the run time quoted beside the step's: the
#: runs measured took 0.5 to 5.5 cycles of ln(ess_min_ratio) / ln(zeta) steps (the OCT
#: example's rounds: 16-74 steps at zeta 0.95)
SMC_CYCLES = 3
#: most hours the GP fits of one study may be estimated to take (all rounds, the final
#: fit and the convergence study together): half a day of one core. The heterogeneous
#: study with the paper's fixed design of 2048 solves is estimated at 0.5 h (measured 34 min)
MAX_GP_HOURS = 12.0
#: most minutes one tempering step of SMC (n_rej sweeps of every particle) may be estimated
#: to take. The number of steps is not known before the run (it grows with what the data
#: say: tens to hundreds), the cost of one step is; a run of 10-minute steps takes hours to
#: days. The heaviest shipped study, heterogeneous_outputs (10000 particles, 30 sweeps, the
#: output emulator's 30 GPs with their variances on 512 solves), is estimated at 5 min a step
MAX_SMC_STEP_MINUTES = 10.0
#: most design points (forward solves) of one study: each is a solve and, in a fixed
#: design, a job the workflow plans at every start; far more than a GP can learn from
#: (its fit grows as n^3: 20000 points take about 5 days per optimizer start)
MAX_DESIGN_POINTS = 20_000


@dataclass(frozen=True)
class Estimate:
    """An estimated wall time and what it is made of.

    Attributes
    ----------
    seconds
        The estimate, s.
    detail
        How it was reached, in words (for the refusal's message).
    """

    seconds: float
    detail: str


def duration(seconds: float) -> str:
    """A wall time in words: ``"0.25 s"``, ``"45 s"``, ``"12 min"``, ``"3.5 h"``,
    ``"2.1e+03 days"``."""
    s = float(seconds)
    if s < 10:
        return f"{s:.2g} s"
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 48 * 3600:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.3g} days"


def _hyperparameters(ard: bool, d: int) -> int:
    return d + 2 if ard else 3


def gp_fit_seconds(n: int, *, starts: float, d: int, ard: bool = True,
                   quadratic: bool = False) -> float:
    """Estimated seconds of ``starts`` optimizer starts of a GP on ``n`` training
    points in ``d`` dimensions (module docstring).

    Parameters
    ----------
    n
        Training points.
    starts
        Optimizer starts in all (candidates x restarts).
    d
        Parameters (inputs).
    ard
        One length scale per input (else one for all).
    quadratic
        The quadratic prior mean (about five times the constant mean's cost).
    """
    per = (GP_START_S + GP_CUBIC_S * float(n) ** 3) * _hyperparameters(ard, d) / 9.0
    return float(starts) * per * (5.0 if quadratic else 1.0)


def tempering_steps(zeta: float, ess_min_ratio: float, max_steps: int) -> int:
    """Estimated tempering steps of one SMC run: :data:`SMC_CYCLES` resampling cycles of
    ``ln(ess_min_ratio) / ln(zeta)`` steps (at least one), at most ``max_steps``."""
    per_cycle = 1
    if 0.0 < ess_min_ratio < 1.0 and 0.0 < zeta < 1.0:
        per_cycle = max(1, math.ceil(math.log(ess_min_ratio) / math.log(zeta)))
    return int(min(int(max_steps), SMC_CYCLES * per_cycle))


def smc_step_seconds(*, n_particles: int, n_rej: int, n_train: int, d: int,
                     emulator_gps: int = 0) -> float:
    """Estimated seconds of one tempering step of SMC: ``n_rej`` Metropolis-Hastings sweeps
    of ``n_particles`` particles on a surrogate of ``n_train`` training points in ``d``
    dimensions: the log-likelihood GP's mean, or (``emulator_gps`` > 0) the output
    emulator's GPs, each with its predictive variance."""
    if emulator_gps > 0:
        per = float(emulator_gps) * (SMC_KERNEL_S * float(n_train) * d
                                     + SMC_VARIANCE_S * float(n_train) ** 2)
    else:
        per = SMC_KERNEL_S * float(n_train) * d
    return float(n_rej) * (SMC_SWEEP_S + float(n_particles) * (SMC_PARTICLE_S + per))


def design_sizes(design: Mapping[str, Any]) -> list[int]:
    """Training points of each round's GP fit of an active design, round 0 first:
    ``n_initial``, then ``batch_size + check_points`` more per round, up to ``max_solves``
    (the final fit on ``max_solves`` is not listed). A fixed design: its one fit on
    ``n_train`` points."""
    if design["strategy"] != "active":
        return [int(design["n_train"])]
    act = design["active"]
    n, top = int(act["n_initial"]), int(act["max_solves"])
    step = max(1, int(act["batch_size"]) + int(act["check_points"]))
    if n >= top:
        return [min(n, top)]
    rounds = math.ceil((top - n) / step)
    return [min(n + r * step, top) for r in range(rounds)]


def _bounds(cfg: Mapping[str, Any]) -> np.ndarray:
    from bayescalib.inference.parameters import ParameterSpace

    return ParameterSpace.from_config(cfg["parameters"]).bounds


def _gp_starts(cfg: Mapping[str, Any], bounds: np.ndarray) -> tuple[int, str]:
    """Candidate models of one full search and their description."""
    from bayescalib.inference.gp import search_size

    sur = cfg["surrogate"]
    if sur["target"] == "outputs":
        k = int(sur["outputs"]["max_components"]) + 1
        return k, f"up to {k} GPs (surrogate.outputs.max_components = {k - 1}, one per output)"
    k = search_size(sur, bounds)
    auto = [key for key in ("kernel", "output", "frame", "inputs") if sur[key] == "auto"]
    return k, (f"{k} candidate model{'s' if k > 1 else ''}"
               + (f" (surrogate.{', '.join(auto)}: auto)" if auto and k > 1 else ""))


def study_gp_seconds(cfg: Mapping[str, Any], *, restarts: int | None = None) -> Estimate:
    """Estimated seconds of all GP fits of a validated study: every round's (or the fixed
    design's), the final surrogate's and the convergence study's fits.

    Parameters
    ----------
    cfg
        The validated study configuration.
    restarts
        Optimizer starts per candidate (None: ``surrogate.restarts``).
    """
    from bayescalib.inference.gp import resolve_ard, resolve_mean

    sur = cfg["surrogate"]
    bounds = _bounds(cfg)
    d = int(bounds.shape[0])
    r = int(sur["restarts"] if restarts is None else restarts)
    ard = True if sur["target"] == "outputs" else resolve_ard(sur["ard"], d)
    quadratic = sur["target"] != "outputs" and resolve_mean(sur["mean"], d) == "quadratic"
    cand, what = _gp_starts(cfg, bounds)
    sizes = design_sizes(cfg["design"])
    growth = float(sur["reselect_growth"])
    total, searched = 0.0, None
    # the growth schedule's searches; a misprediction (surrogate.reselect_error) can add
    # some, which cannot be known before the rounds run
    for n in sizes:
        full = searched is None or growth <= 0 or n >= (1.0 + growth) * searched
        searched = n if full else searched
        starts = cand * r if full else r + 1  # a refit: the previous choice, a warm start more
        total += gp_fit_seconds(n, starts=starts, d=d, ard=ard, quadratic=quadratic)
    fits = len(sizes)
    top = max(sizes)
    if cfg["design"]["strategy"] == "active":  # the final surrogate: a full search on all
        top = int(cfg["design"]["active"]["max_solves"])
        total += gp_fit_seconds(top, starts=cand * r, d=d, ard=ard, quadratic=quadratic)
        fits += 1
    conv = cfg["convergence"]
    if conv["enabled"]:
        for n in conv["n_train"]:
            total += gp_fit_seconds(int(n), starts=cand * r, d=d, ard=ard, quadratic=quadratic)
        fits += len(conv["n_train"])
    return Estimate(total, f"{fits} fit{'s' if fits > 1 else ''} of {what}, {r} optimizer "
                           f"start{'s' if r > 1 else ''} each, on up to {top} "
                           f"training points in {d} dimensions")


def study_smc_steps(cfg: Mapping[str, Any]) -> list[tuple[str, dict[str, Any], Estimate]]:
    """Estimated seconds of one tempering step of each kind of SMC run of a validated
    study, on its largest surrogate: ``(section, settings, estimate)`` with section
    ``"smc"`` (the final run; for an active design without ``design.active.smc`` the
    rounds' runs) and, for an active design with ``design.active.smc``,
    ``"design.active.smc"`` (the rounds' runs; ``settings``: ``smc`` with its overrides)."""
    from bayescalib.config import round_smc

    d = int(_bounds(cfg).shape[0])
    sur = cfg["surrogate"]
    gps = int(sur["outputs"]["max_components"]) if sur["target"] == "outputs" else 0
    act = cfg["design"]["active"]
    active = cfg["design"]["strategy"] == "active"
    top = int(act["max_solves"]) if active else int(cfg["design"]["n_train"])
    runs: list[tuple[str, dict[str, Any], int]] = [("smc", dict(cfg["smc"]), top)]
    if active and act.get("smc"):
        runs.append(("design.active.smc", round_smc(cfg["smc"], act),
                     max(design_sizes(cfg["design"]))))
    out = []
    for section, smc, n in runs:
        steps = tempering_steps(smc["zeta"], smc["ess_min_ratio"], smc["max_steps"])
        t = smc_step_seconds(n_particles=smc["n_particles"], n_rej=smc["n_rej"], n_train=n,
                             d=d, emulator_gps=gps)
        what = ("the output emulator's " + f"{gps} GPs" if gps else "a GP") + \
            f" of {n} training points in {d} dimensions"
        out.append((section, smc, Estimate(t, (
            f"{smc['n_rej']} sweeps x {smc['n_particles']} particles on {what}; at zeta "
            f"{smc['zeta']:g} a run takes about {steps} steps, more when the data say "
            f"much: {duration(steps * t)}"))))
    return out
