"""The ``diagnose`` stage: check, locate, attribute, model, show (writes diagnosis.json).

In this module "check" is always the *predictive check*
(:func:`bayescalib.diagnosis.residuals.predictive_check`; a variable ``check`` holds
one, ``diagnosis.json``'s ``check`` is the base model's, ``check_after`` a re-check's),
never the rounds' trust or posterior check (docs/glossary.md).

0. *Start* from the study's own calibration: the posterior that ``summary.json``
   reports, with its design block (active rounds converged or not). The diagnosis does
   not re-calibrate the base model; when its calibration did not converge it says so,
   because a mismatch may then be the surrogate's and not the physics'.
1. *Check* — K posterior draws of the base calibration (systematic resampling of the
   SMC particles, seeded) are solved; :func:`~bayescalib.diagnosis.residuals.predictive_check`
   gives the residual along the observed interface with its predictive bands and the
   global p-values.
2. *Locate* — the arc-length intervals where the smoothed residual leaves its
   simultaneous band (on a 3D surface: connected regions of its nodes, named by their
   place on the colony).
3. *Attribute* — solves at the posterior mean, at finite-difference steps of every
   calibrated parameter and at a step of each candidate's ``phi`` give the nuisance
   Jacobian and the candidates' signatures;
   :func:`~bayescalib.diagnosis.attribution.attribute` ranks the candidates.
4. *Model* — for the ``n_extend`` best-ranked identifiable candidates (when the check
   fails, or always with ``force_extend``), the extended model is calibrated by the
   same active-design chain as the study
   (:func:`~bayescalib.diagnosis.extended.extended_calibration`, which says whether it
   converged) and compared by its log Bayes factor (then, when the single extensions
   call for it, the joint model of the best of them: :func:`joint_of_singles`). One
   that its budget stopped unconverged is represented by whichever of its last two
   rounds' posteriors the real solves of step 5 confirm better
   (:func:`_better_confirmed_round`): the last round's posterior can have moved where
   no solve has checked the surrogate yet.
5. *Show* — the predictive check is repeated with draws of each extended posterior:
   residual RMS, band coverage and p-values before/after, the posterior of ``phi``,
   and the change of the base parameters' error against the ground truth when known.
   Where two rounds were compared, the round kept is the one whose draws happened to
   fit better, so their RMS is biased low (the minimum of two noisy estimates); the
   check that is reported, and that decides whether the extension explains the
   mismatch, comes from *fresh* draws of the kept posterior (another seed,
   :data:`REPORT_SEED_OFFSET`), solved for the report only (:func:`_reported_predictive_check`).
   Every check gives the spread of its RMS over the draws
   (:func:`~bayescalib.diagnosis.residuals.rms_spread`: per-draw median and 16-84 %
   range, and a bootstrap interval over the draws).

A candidate whose signature solve fails at its step is tried again (:func:`retry_steps`:
the opposite sign, half steps; then from the solved posterior draw nearest the mean);
one that no attempt could solve is *not testable* and the verdict names it instead of
saying that no candidate explains the mismatch. Candidates selected together by the
attribution are also calibrated together (one extended model with both ``phi``). The
attribution sees each effect through its first-order signature only and may not select
two that are present at once; so when two or more *single* extensions each fit
significantly better than the base model and none explains the mismatch alone, the
joint model of the best of them is calibrated too (:func:`joint_of_singles`, up to
``diagnose.max_effects``; :func:`model_extensions`), and the plain words say why.

Nothing is set aside unseen: every candidate no extended model contains (not
identifiable, a significant one whose estimated magnitude lies outside its plausible
range, a significant one ranked below the ``n_extend`` calibrated, one not testable) is
recorded with its estimate, the range it violates and what the user could do
(:func:`set_aside_candidates`; ``set_aside`` of diagnosis.json, the plain words and the
report), and while one of them alone would explain most of the mismatch the verdict
says so instead of "no candidate explains it".

Not every mismatch is physics: a rigid misregistration of the observed interfaces
(``diagnose.registration``; :mod:`bayescalib.geometry.registration`) is tested as a
block of nuisance effects (:func:`~bayescalib.diagnosis.attribution.block_test`) and,
when significant, re-checked with the observations registered back (the same draws'
solves); in 2D only (its signatures are in-plane moves), and the plain words of a 3D
diagnosis say it was not tested. A mismatch located on the zero-load snapshot is
reported as not flow-driven.

The 3D model (observed surfaces) goes through the same steps: the residual lives on a
Poisson-disk subset of each observed surface's vertices
(:func:`~bayescalib.diagnosis.context.diagnosis_nodes`; a volume's without the layer of
voxels above its cut), the candidate library is the same (the 3D model has every
candidate: :data:`bayescalib.models.fsi.model.PHYSICS_3D`), and everything downstream of
the residual vector (signatures, attribution, extended calibrations, verdict) is the same
code.

The chosen model (:func:`choose_extension`) is, among the extended models whose real
forward solves at their posterior draws *explain* the mismatch
(:func:`explains_mismatch`: the check passes or the residual RMS is within
:data:`EXPLAINED_RMS` times the noise), the one with the largest log Bayes factor, if
that exceeds ``ln 3``; otherwise the base model. The
verdict (:func:`decide_verdict`) is decided after the modelling, so it never names a
cause the chosen model does not contain.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

# the observation noise settings are resolved with the context (and kept here by name)
from bayescalib.diagnosis.context import (
    IMAGE_NOISE_LAG_PIXELS,
    DiagnosisContext,
    noise_lag,
    resolve_noise_model,
    thinned_observations,
)
from bayescalib.diagnosis.extended import CandidateSpec, extended_calibration, joint_name
from bayescalib.inference.posterior import equal_weight_draws
from bayescalib.stages.discrepancy import model_interfaces
from bayescalib.stages.files import read_stage_file

__all__ = ["DISCRETIZED", "IMAGE_NOISE_LAG_PIXELS", "MIN_IDENTIFIABLE",
           "choose_extension", "corrected_for_mesh", "decide_verdict",
           "explains_mismatch", "fits_better", "joint_of_singles", "judge_extensions",
           "model_extensions", "noise_lag", "plain_words", "reference_noise",
           "resolve_candidates", "resolve_noise_model", "retry_steps", "run_diagnosis",
           "set_aside_candidates", "thinned_observations", "widened_range",
           "with_discretization"]

log = logging.getLogger(__name__)

ABSORBED = "mismatch absorbed by the base parameters; calibration off, no physics missing"

MISREGISTERED = ("mismatch explained by a misregistration of the observed interfaces "
                 "(not physics)")

#: the same from one snapshot: a rigid misplacement and physics that moves the interface
#: nearly as a whole look alike there (a misplacement is the same at every load, a
#: flow-driven effect is not, and neither is anything at zero load but the rest shape)
MISREGISTERED_OR_PHYSICS = (
    "mismatch explained by a misregistration of the observed interfaces, or by physics "
    "that moves them nearly as a whole (one snapshot: the data cannot tell them apart)")

LN_BF_MIN = math.log(3.0)

#: the verdict when the discretization check explains the mismatch and no extension does
DISCRETIZED = ("mismatch within the forward model's discretization error (refine the mesh "
               "before reading physics into it)")

#: an extension (or a registration) explains the mismatch when its re-check passes or
#: its residual RMS is within this factor of the noise sd
EXPLAINED_RMS = 1.5

#: a candidate at most this fraction of whose signature lies beyond what the base
#: parameters can mimic (``identifiable_fraction``) is not identifiable: set aside
MIN_IDENTIFIABLE = 0.05

#: what the user can do about a candidate whose signature solves all failed
NOT_TESTABLE_ADVICE = ("make the forward model solve with it switched on (the solver's "
                       "reasons per attempt: diagnosis.json, signature_attempts) and "
                       "rerun the diagnosis")

#: signature solves tried at the posterior mean after the candidate's step failed
N_RETRY_STEPS = 3

#: added to ``diagnose.seed`` for the posterior draws solved for the report of an
#: extension whose round was chosen by real solves (:func:`_reported_predictive_check`)
REPORT_SEED_OFFSET = 1000


class PredictiveCheckError(ValueError):
    """Too few posterior draws could be solved for a predictive check."""


def resolve_candidates(fm: Mapping[str, Any], diagnose: Mapping[str, Any]) -> list[CandidateSpec]:
    """The candidates to test: ``diagnose.candidates`` or, for the fsi model, the built-in
    library (:data:`bayescalib.models.fsi.physics.CANDIDATES`) minus those already switched on,
    with the prior ranges of ``diagnose.priors`` (a validated ``diagnose`` section)."""
    given = diagnose.get("candidates")
    if given:
        return [CandidateSpec(name=c["name"], target=c["target"], step=float(c["step"]),
                              prior=(float(c["prior"][0]), float(c["prior"][1])),
                              unit=c["unit"], switches=dict(c["switches"]),
                              summary=c["summary"])
                for c in given]
    if fm.get("type") != "fsi":
        raise ValueError("diagnose.candidates: list the candidate effects of a python or "
                         "command forward model (name, target, step, prior)")
    from bayescalib.models.fsi.physics import CANDIDATES

    physics = (fm.get("fsi") or {}).get("physics") or {}
    out = []
    for name, c in CANDIDATES.items():
        if (physics.get(name) or {}).get("enabled"):
            continue  # already part of the model being diagnosed
        out.append(CandidateSpec(name=name, target=c.key, step=c.typical,
                                 prior=tuple(diagnose["priors"][name]), unit=c.unit,
                                 switches={f"physics.{name}.enabled": True}, summary=c.summary,
                                 continuous=c.continuous))
    return out


# ------------------------------------------------------------------------- helpers
@dataclass(frozen=True)
class CheckedModel:
    """A model whose posterior draws are solved for a predictive check: the base model or
    an extension.

    Attributes
    ----------
    tag : its folder under the work folder (and its name in messages).
    targets : the columns of its SMC particles (the base parameters', then each ``phi``).
    switches : forward-model settings added to every solve (the extension's).
    sigma : the noise sd given to its predictive checks, mm (None: estimated).
    """

    tag: str
    targets: list[str]
    switches: Mapping[str, Any]
    sigma: float | None


@dataclass(frozen=True)
class BaseCalibration:
    """The study's calibration as ``summary.json`` reports it (step 0): its SMC particle
    file and log evidence, its posterior summary and its design block (strategy, solves,
    converged, reason)."""

    particles: str | Path
    log_evidence: float
    summary: Mapping[str, Any]
    design: dict[str, Any]

    @classmethod
    def read(cls, particles: str | Path, posterior: str | Path,
             design: Mapping[str, Any]) -> BaseCalibration:
        return cls(particles,
                   float(read_stage_file(particles, "SMC particle file").log_evidence),
                   read_stage_file(posterior, "posterior summary"),
                   {k: design.get(k) for k in ("strategy", "n_solves", "converged", "reason")})


def _offsets_from(observed: Sequence[np.ndarray], reference: Sequence[Any],
                  curves: Sequence[Sequence[Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Residual of the observed nodes and offsets of ``curves`` (per snapshot each)
    from the ``reference`` prediction, over all snapshots."""
    from bayescalib.diagnosis.residuals import offsets

    ys, os_ = [], []
    for s in range(len(observed)):
        y, o = offsets(observed[s], reference[s], [cv[s] for cv in curves])
        ys.append(y)
        os_.append(o)
    return np.concatenate(ys), np.concatenate(os_, axis=1)


@dataclass(frozen=True)
class Linearization:
    """The base model linearized at its posterior mean (step 3).

    Attributes
    ----------
    targets : the base parameters' targets.
    theta : the posterior mean (parameter order).
    lo, hi : the parameters' box.
    h : the finite-difference steps (towards the box interior).
    fd : the parameters whose step solved (the columns of ``J``).
    observed : the observed nodes per snapshot (the diagnosis's: thinned).
    reference : the predicted interfaces at the posterior mean, per snapshot.
    r : the residual of the observed nodes from ``reference``, all snapshots.
    J : the nuisance Jacobian of the offsets (columns ``fd``).
    """

    targets: list[str]
    theta: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    h: np.ndarray
    fd: list[int]
    observed: list[np.ndarray]
    reference: list[Any]
    r: np.ndarray
    J: np.ndarray

    @property
    def base_point(self) -> dict[str, float]:
        return dict(zip(self.targets, map(float, self.theta), strict=True))

    @property
    def n_snap(self) -> int:
        return len(self.observed)

    def offsets_of(self, curves: Sequence[Sequence[Any]]) -> tuple[np.ndarray, np.ndarray]:
        """Residual and offsets from the posterior-mean prediction, over all snapshots."""
        return _offsets_from(self.observed, self.reference, curves)


@dataclass(frozen=True)
class Attribution:
    """What step 3 found: the linearization, the candidates tested, the attribution
    (:func:`~bayescalib.diagnosis.attribution.attribute`, its ranking annotated for the
    report), the candidates no signature solve could evaluate (name -> reasons) and
    every signature attempt (:func:`_signatures`)."""

    lin: Linearization
    cands: list[CandidateSpec]
    result: dict[str, Any]
    failed: dict[str, str]
    attempts: dict[str, Any]


@dataclass(frozen=True)
class Screening:
    """The verdict before any modelling (step 4's gate): the re-fit test (``refit``:
    whether the base parameters absorb the mismatch), the screening verdict and whether
    extended models are calibrated (``extend``)."""

    refit: dict[str, Any]
    verdict: str
    extend: bool


@dataclass(frozen=True)
class Extensions:
    """Steps 4-5: the calibrated extensions, each judged by real solves
    (:func:`model_extensions`), the reference noise sd they were judged against (mm)
    and the joint model of singles (None: none)."""

    extended: list[dict[str, Any]]
    noise_reference: float
    joint: dict[str, Any] | None


@dataclass(frozen=True)
class Decision:
    """What the diagnosis decided: its screening and extensions, the candidates set
    aside, the chosen model and the verdict."""

    screening: Screening
    extensions: Extensions
    set_aside: list[dict[str, Any]]
    chosen: str
    verdict: str


def _residual_variance(check) -> np.ndarray:
    """The variance of the residual at every observed node (noise and posterior spread)
    of a predictive check, all snapshots."""
    return np.concatenate([sn.v for sn in check.snapshots])


def _recheck_sigma(ctx: DiagnosisContext, check) -> float | None:
    """The noise sd given to the predictive checks after the base model's (extensions,
    registered observations): the base check's when it was given, else the context's
    (None: each estimates its own)."""
    return check.sigma if check.sigma_source == "given" else ctx.sigma


def _predictive_check_at_draws(ctx: DiagnosisContext, model: CheckedModel,
                               particles: str | Path, tag: str, seed: int):
    """Solve posterior draws of ``model`` and run the predictive check.

    ``diagnose.n_draws`` draws of the SMC particles ``particles`` (systematic
    resampling seeded by ``seed``; the noise replicates by ``seed + 1``) are solved under
    ``<work>/<tag>/draws``.

    Returns the check, the number of failed draws and the draws: ``X`` (K, d), ``ok``
    (K,) and ``curves`` (the predicted interfaces of the solved draws, per snapshot).
    """
    X = equal_weight_draws(read_stage_file(particles, "SMC particle file"),
                           int(ctx.settings["n_draws"]), int(seed))
    points = [{**dict(zip(model.targets, map(float, x), strict=True)), **model.switches}
              for x in X]
    runs = ctx.solve(points, Path(tag) / "draws")
    good = [r for r in runs if r.ok]
    if len(good) < 2:
        reasons = sorted({r.reason.split(";")[0] for r in runs if not r.ok})
        raise PredictiveCheckError(
            f"diagnosis ({tag}): only {len(good)} of {len(runs)} posterior draws solved; the "
            "predictive check needs at least 2. Failures: " + "; ".join(reasons[:3]))
    curves = [model_interfaces(r, ctx.n_snap) for r in good]
    check = ctx.predictive_check(ctx.nodes, curves, model.sigma, seed)
    draws = {"X": X, "ok": np.array([r.ok for r in runs]), "curves": curves}
    return check, len(runs) - len(good), draws


def retry_steps(cand: CandidateSpec) -> list[float]:
    """Steps of ``phi`` tried after the signature solve at ``cand.step`` failed: the
    opposite sign (a one-sided difference the other way), then half and quarter steps,
    each only where the candidate's prior range allows it; at most
    :data:`N_RETRY_STEPS`."""
    lo, hi = (float(x) for x in cand.prior)
    st = float(cand.step)
    out = [x for x in (-st, 0.5 * st, -0.5 * st, 0.25 * st, -0.25 * st)
           if x != 0.0 and lo <= x <= hi]
    return out[:N_RETRY_STEPS]


def _better_confirmed_round(ctx: DiagnosisContext, cal: dict[str, Any], after,
                            n_fail_after: int, model: CheckedModel):
    """The round that represents an extended calibration that stopped unconverged.

    When the budget ends an active design, the last round's posterior may have moved
    to where no solve has checked the surrogate yet (the next round would have). So the
    posterior of the round before is re-checked with real solves too, and the round
    whose posterior the real solves confirm better (smaller residual RMS of the
    predictive check) represents the extension: its posterior, SMC log evidence and
    particles. A converged calibration, one of a single round, or one whose last round
    could not be solved is returned as it is.

    Returns
    -------
    cal, after, n_fail_after
        As given, or those of the round before.
    rechecked : dict or None
        ``{round: residual RMS (mm)}`` of the rounds re-checked (None: no second check).
    """
    from bayescalib.stages.marginalize import marginalize

    rounds = cal.get("rounds") or []
    if cal["converged"] or len(rounds) < 2 or after is None:
        return cal, after, n_fail_after, None
    last = int(rounds[-1]["round"])
    # the round's own files: the result's may be a full search in the folder above them
    rd = Path(cal["workdir"]) / "active" / str(last - 1)
    try:
        alt, n_fail_alt, _ = _predictive_check_at_draws(
            ctx, model, rd / "particles.h5", f"{model.tag}/round_{last - 1}",
            int(ctx.settings["seed"]))
    except PredictiveCheckError as exc:
        log.warning("%s", exc)
        return cal, after, n_fail_after, {last: float(after.rms)}
    rechecked = {last: float(after.rms), last - 1: float(alt.rms)}
    if alt.rms >= after.rms:
        return cal, after, n_fail_after, rechecked
    log.info("%s: round %d's posterior fits better at real solves than the last round's "
             "(%.3g vs %.3g mm); it represents the extension", model.tag, last - 1, alt.rms,
             after.rms)
    summary = marginalize(rd / "particles.h5", rd / "surrogate.h5", ctx.posterior_cfg,
                          cal["parameters"], int(ctx.smc_cfg["seed"]),
                          rd / "posterior.json", rd / "posterior.nc")
    cal = {**cal, "posterior": summary, "particles": str(rd / "particles.h5"),
           "surrogate": str(rd / "surrogate.h5"), "reported_round": last - 1,
           "log_evidence": float(read_stage_file(rd / "particles.h5",
                                                 "SMC particle file").log_evidence)}
    return cal, alt, n_fail_alt, rechecked


def _reported_predictive_check(ctx: DiagnosisContext, cal: Mapping[str, Any], after,
                               n_fail_after: int, rechecked: Mapping[int, float] | None,
                               model: CheckedModel):
    """The predictive check reported for an extension, unbiased by the choice of its
    round.

    :func:`_better_confirmed_round` keeps, of two rounds, the one whose real solves fit
    better: the kept check's RMS is the smaller of two estimates that each vary with
    their K draws (1.14-1.61 um over three sets of 16 draws of one posterior), so it is
    biased low. Where two rounds were compared (``rechecked`` has two entries), K
    *fresh* draws of the kept posterior (seed ``diagnose.seed +``
    :data:`REPORT_SEED_OFFSET`) are solved through the same solve path and their check
    is the one reported and judged (:func:`explains_mismatch`); the draws that chose
    the round are not used again. Elsewhere nothing was chosen on the draws and the
    check is returned as it is.

    Returns
    -------
    after, n_fail_after
        The check to report (None when no fresh draw solved) and its failed draws.
    source : dict
        ``draws`` (``"fresh"`` or ``"check"``: the draws of the check that decided
        nothing), ``seed``, ``n_draws``, ``n_failed``; for fresh draws also
        ``selection_rms_mm`` (the kept round's RMS at the draws that chose it) and,
        when none solved, ``failed`` (the reason).
    """
    seed = int(ctx.settings["seed"])
    n_draws = int(ctx.settings["n_draws"])
    if rechecked is None or len(rechecked) < 2:
        return after, n_fail_after, {"draws": "check", "seed": seed, "n_draws": n_draws,
                                     "n_failed": int(n_fail_after)}
    kept = cal.get("reported_round")
    kept = max(int(k) for k in rechecked) if kept is None else int(kept)
    source = {"draws": "fresh", "seed": seed + REPORT_SEED_OFFSET, "n_draws": n_draws,
              "selection_rms_mm": float({int(k): v for k, v in rechecked.items()}[kept])}
    try:
        fresh, n_fail, _ = _predictive_check_at_draws(
            ctx, model, cal["particles"], f"{model.tag}/report", seed + REPORT_SEED_OFFSET)
    except PredictiveCheckError as exc:
        log.warning("%s", exc)
        return None, n_draws, {**source, "n_failed": n_draws, "failed": str(exc)}
    log.info("%s: residual RMS at fresh draws of the kept round %.3g mm (%.3g mm at the "
             "draws that chose it)", model.tag, fresh.rms, source["selection_rms_mm"])
    return fresh, n_fail, {**source, "n_failed": int(n_fail)}


def _linearize(ctx: DiagnosisContext, mean: Mapping[str, float],
               cands: Sequence[CandidateSpec]) -> tuple[Linearization, list]:
    """Solve at the posterior mean ``mean``, at a finite-difference step of every
    parameter (towards the box interior, so the point stays inside the prior support)
    and at each candidate's step; the linearization and the candidates' solves."""
    from bayescalib.diagnosis.attribution import jacobian_from_offsets

    targets = ctx.targets
    theta = np.array([float(mean[n]) for n in ctx.names])
    lo, hi = ctx.bounds()
    h = float(ctx.settings["fd_step"]) * (hi - lo)
    h = np.where(theta + h > hi, -h, h)
    base_point = dict(zip(targets, map(float, theta), strict=True))
    pts = [base_point]
    for i, t in enumerate(targets):
        pts.append({**base_point, t: float(theta[i] + h[i])})
    for c in cands:
        pts.append({**base_point, c.target: c.step, **c.switches})
    runs = ctx.solve(pts, "base/linearization")
    if not runs[0].ok:
        raise ValueError(f"diagnosis: the solve at the posterior mean failed ({runs[0].reason})")
    reference = model_interfaces(runs[0], ctx.n_snap)
    observed = ctx.nodes
    r, _ = _offsets_from(observed, reference, [])
    fd = [i for i in range(len(targets)) if runs[1 + i].ok]
    _, O_fd = _offsets_from(observed, reference,
                            [model_interfaces(runs[1 + i], ctx.n_snap) for i in fd])
    # offsets are measured from the posterior-mean prediction, so its own offset is 0
    J = jacobian_from_offsets(list(O_fd), np.zeros(len(r)), [h[i] for i in fd])
    lin = Linearization(targets, theta, lo, hi, h, fd, observed, reference, r, J)
    return lin, runs[1 + len(targets):]


def _signatures(ctx: DiagnosisContext, lin: Linearization, cands: Sequence[CandidateSpec],
                first: Sequence[Any], draws: Mapping[str, Any]):
    """Candidate signatures, trying harder where the solve at the step failed.

    ``first`` are the solves at the posterior mean with each candidate at its step. A
    candidate whose solve failed is tried again with :func:`retry_steps` at the
    posterior mean, then at its step from the solved posterior draw nearest to the mean
    (distance scaled by the box), where the signature is the difference to that
    draw's own prediction. A candidate no attempt could solve is *not testable*.

    Returns
    -------
    signatures : dict
        ``name -> (n,)`` signature, mm per unit phi.
    failed : dict
        ``name -> reasons`` of the candidates that could not be evaluated.
    attempts : dict
        ``name -> {"phi_step", "at", "tried": [...]}``: the step and place used and
        every attempt with its outcome.
    """
    from bayescalib.diagnosis.attribution import signature_from_offsets

    n_snap = lin.n_snap
    signatures, attempts = {}, {}
    for c, run in zip(cands, first, strict=True):
        attempts[c.name] = {"phi_step": c.step, "at": "posterior mean", "tried": [
            {"phi_step": c.step, "at": "posterior mean", "ok": bool(run.ok),
             "reason": "" if run.ok else run.reason}]}
        if run.ok:
            _, O = lin.offsets_of([model_interfaces(run, n_snap)])
            signatures[c.name] = signature_from_offsets(O[0], 0.0, c.step)
    todo = [c for c in cands if c.name not in signatures]
    if not todo:
        return signatures, {}, attempts
    base_point = lin.base_point
    ok = np.flatnonzero(draws["ok"])
    near, draw_point = None, None
    if ok.size:
        dist = np.linalg.norm((draws["X"][ok] - lin.theta) / (lin.hi - lin.lo), axis=1)
        near = int(np.argmin(dist))  # index into the solved draws (draws["curves"])
        draw_point = dict(zip(lin.targets, map(float, draws["X"][ok[near]]), strict=True))
    pts, meta = [], []
    for c in todo:
        for st in retry_steps(c):
            pts.append({**base_point, c.target: st, **c.switches})
            meta.append((c, st, None))
        if draw_point is not None:
            for st in [c.step, *retry_steps(c)[:1]]:
                pts.append({**draw_point, c.target: st, **c.switches})
                meta.append((c, st, near))
    runs = ctx.solve(pts, "base/signatures")
    for (c, st, k), run in zip(meta, runs, strict=True):
        at = "posterior mean" if k is None else f"posterior draw {int(ok[k])}"
        attempts[c.name]["tried"].append({"phi_step": st, "at": at, "ok": bool(run.ok),
                                          "reason": "" if run.ok else run.reason})
        if c.name in signatures or not run.ok:
            continue
        if k is None:
            _, O = lin.offsets_of([model_interfaces(run, n_snap)])
            signatures[c.name] = signature_from_offsets(O[0], 0.0, st)
        else:
            _, O = lin.offsets_of([draws["curves"][k], model_interfaces(run, n_snap)])
            signatures[c.name] = signature_from_offsets(O[1], O[0], st)
        attempts[c.name].update(phi_step=st, at=at)
    failed = {}
    for c in todo:
        if c.name not in signatures:
            reasons = dict.fromkeys(a["reason"].split(";")[0]
                                    for a in attempts[c.name]["tried"])
            failed[c.name] = "; ".join(reasons)
    return signatures, failed, attempts


def _attribute(ctx: DiagnosisContext, mean: Mapping[str, float], check,
               draws: Mapping[str, Any]) -> Attribution:
    """Step 3: linearize at the posterior mean ``mean``, solve the candidates'
    signatures (:func:`_signatures`) and rank the candidates
    (:func:`~bayescalib.diagnosis.attribution.attribute`) against the base predictive
    check's residual variance."""
    from bayescalib.diagnosis.attribution import attribute

    cfg = ctx.settings
    cands = resolve_candidates(ctx.fm, cfg)
    lin, cand_runs = _linearize(ctx, mean, cands)
    signatures, failed, attempts = _signatures(ctx, lin, cands, cand_runs, draws)
    attr = attribute(lin.r, lin.J, signatures, _residual_variance(check), alpha=cfg["alpha"],
                     r2_min=cfg["r2_min"], max_effects=cfg["max_effects"],
                     ranges={c.name: c.prior for c in cands})
    # plain-words size of each signature's effect at the step, for the report
    for row in attr["ranking"]:
        c = next(c for c in cands if c.name == row["candidate"])
        row["summary"] = c.summary
        row["step"] = attempts[c.name]["phi_step"]
        row["signature_at"] = attempts[c.name]["at"]
        row["unit"] = c.unit
        row["max_shift_at_step_mm"] = float(np.max(np.abs(signatures[c.name] * c.step)))
    return Attribution(lin, cands, attr, failed, attempts)


def _registration(ctx: DiagnosisContext, lin: Linearization, check,
                  draws: Mapping[str, Any]) -> dict:
    """Test and, when significant, model a rigid misregistration of the observations.

    The block test (:func:`~bayescalib.diagnosis.attribution.block_test`) at the posterior
    mean says whether a misplacement beyond what E, nu, ... absorb is significant. If so,
    the base parameters and the registration are fitted jointly by damped Gauss-Newton
    with real solves (:func:`~bayescalib.diagnosis.registration.joint_fit`; the base
    posterior may sit far from the joint fit because it absorbed the misplacement), and
    the registered observations are checked against solved draws of the joint fit's
    Laplace posterior (:func:`~bayescalib.diagnosis.registration.laplace_draws`).
    """
    from bayescalib.diagnosis.attribution import block_test, jacobian_from_offsets
    from bayescalib.diagnosis.registration import joint_fit, laplace_draws
    from bayescalib.diagnosis.residuals import offsets, registration_signatures
    from bayescalib.geometry.interface import Interface
    from bayescalib.geometry.registration import register

    cfg, obs, names = ctx.settings, ctx.obs, ctx.names
    modes = list(cfg["registration"])
    targets, theta, h, fd, lo, hi = lin.targets, lin.theta, lin.h, lin.fd, lin.lo, lin.hi
    obs_pts, n_snap = lin.observed, lin.n_snap
    centre = obs_pts[0].mean(axis=0)
    B = np.concatenate([registration_signatures(obs_pts[s], lin.reference[s], centre, modes)
                        for s in range(n_snap)])
    out = block_test(lin.r, lin.J, B, _residual_variance(check), modes)
    out["centre_mm"] = [float(x) for x in centre]
    out["significant"] = bool(out["p_value"] < float(cfg["alpha"]))
    # accounts for the mismatch to first order (as the attribution's r2_min asks)
    out["first_order"] = bool(out["explained_fraction"] >= float(cfg["r2_min"]))
    out["check_after"] = None
    out["explains"] = False
    out["iterations"] = []
    step0 = np.zeros(len(targets))
    step0[fd] = out["base_step"]
    out["base_step"] = dict(zip([names[i] for i in fd], out["base_step"], strict=True))
    if not out["significant"] or check.adequate:
        return out
    solve_no = itertools.count()

    def evaluate(th: np.ndarray, est: Mapping[str, float]):
        """Residual, Jacobian and registration signatures of the registered observations."""
        pts = [dict(zip(targets, map(float, th), strict=True))]
        pts += [{**pts[0], targets[i]: float(th[i] + h[i])} for i in fd]
        runs = ctx.solve(pts, f"registration/gauss_newton_{next(solve_no)}")
        if not all(run.ok for run in runs):
            return next(run.reason for run in runs if not run.ok)
        C = model_interfaces(runs[0], n_snap)
        ys, os_, bs = [], [], []
        for s in range(n_snap):
            moved = register(obs_pts[s], est, centre)
            y, o = offsets(moved, C[s], [model_interfaces(run, n_snap)[s] for run in runs[1:]])
            ys.append(y)
            os_.append(o)
            bs.append(registration_signatures(moved, C[s], centre, modes))
        rk = np.concatenate(ys)
        Jk = jacobian_from_offsets(list(np.concatenate(os_, axis=1)), np.zeros(len(rk)),
                                   [h[i] for i in fd])
        return rk, Jk, np.concatenate(bs)

    # the joint fit weighs the observation noise only: v also holds the spread of the
    # base posterior's draws, which the re-fit replaces (with it, a fit at chi2 76 on 128
    # values left 1.7 um against 1 um noise)
    v_noise = np.full(len(lin.r), float(check.sigma) ** 2)
    fit = joint_fit(evaluate, theta + step0, out["estimate"], fd, h, lo, hi, v_noise, modes,
                    names)
    out["iterations"] = fit.iterations
    if fit.J is None:
        out["check_after_failed"] = "no solve of the joint fit succeeded"
        return out
    th, est = fit.theta, fit.estimate
    out["estimate"] = est
    out["refit_parameters"] = dict(zip(names, map(float, th), strict=True))
    moved = [Interface(register(obs_pts[s], est, centre), obs.snapshots[s].cells,
                       name=f"registered {obs.labels[s]}") for s in range(n_snap)]
    # the registered model's own posterior (Laplace at the joint fit, given the fitted
    # registration), not the base posterior's draws moved along: those carry how the base
    # posterior absorbed the misplacement (with another surrogate it absorbed it
    # differently, and the moved draws missed the registered data by 2 um against 1 um)
    Xr = np.clip(draws["X"][draws["ok"]] + (th - theta), lo, hi)
    Xr[:, fd] = laplace_draws(fit.J, v_noise, th[fd], lo[fd], hi[fd], len(Xr),
                              np.random.default_rng(int(cfg["seed"]) + 2))
    out["draws_after"] = "laplace"
    rruns = ctx.solve([dict(zip(targets, map(float, x), strict=True)) for x in Xr],
                      "registration/draws")
    rcurves = [model_interfaces(rr, n_snap) for rr in rruns if rr.ok]
    if len(rcurves) < 2:
        out["check_after_failed"] = "fewer than 2 draws of the registered model solved"
        return out
    after = ctx.predictive_check(moved, rcurves, _recheck_sigma(ctx, check), int(cfg["seed"]))
    out["check_after"] = after.to_json()
    out["explains"] = bool(out["first_order"] and explains_mismatch(out["check_after"], check))
    return out


def corrected_for_mesh(nodes: np.ndarray, here: Any, there: Any
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Observed nodes corrected for the difference between two meshes' predictions.

    Parameters
    ----------
    nodes
        (n, d) observed nodes, mm.
    here, there
        The prediction on the study's mesh and on a finer one (interfaces).

    Returns
    -------
    moved : ndarray, shape (n, d)
        ``x_j - e_j n_j``: each node moved back along the outward normal ``n_j`` of
        ``here`` (at its closest point) by ``e_j``, mm.
    e : ndarray, shape (n,)
        The signed offset of ``there`` from ``here`` at those points (+: outward), mm.
    """
    from bayescalib.diagnosis.residuals import fluid_side_sign
    from bayescalib.geometry.projection import closest_points

    _, O = _offsets_from([nodes], [here], [[there]])
    e = O[0]
    _, _, cell = closest_points(nodes, here)
    nrm = fluid_side_sign(here) * here.normals[cell]
    return nodes - e[:, None] * nrm, e


def with_discretization(verdict: str, extension_chosen: bool,
                        discretization: Mapping[str, Any] | None) -> str:
    """The verdict once the discretization check is known (:func:`_discretization_check`):
    unchanged unless the mesh's error explains the mismatch; then :data:`DISCRETIZED`
    without a chosen extension, or the extension's verdict with the mesh beside it."""
    if discretization is None or not discretization.get("explains"):
        return verdict
    if not extension_chosen:
        return DISCRETIZED
    return (f"{verdict}, or by the forward model's discretization error (refine the mesh to "
            "tell them apart)")


def _discretization_check(ctx: DiagnosisContext, check, draws: Mapping[str, Any],
                          lin: Linearization) -> dict[str, Any] | None:
    """Is the mismatch the forward model's own discretization error?

    The posterior mean, solved on the study's mesh by the linearization (``lin``), is
    solved once more on the next finer preset
    (:func:`~bayescalib.models.fsi.model.finer_preset`); the finer prediction's signed
    offset ``e_j`` from the study's at the observed nodes (+: outward) is the mesh's
    error there, to first order (:func:`corrected_for_mesh`). The observed nodes moved
    back by it (``x_j - e_j n_j``, ``n`` the outward normal of the study's prediction)
    are checked against the same posterior draws: if that check explains the mismatch
    (:func:`explains_mismatch`), the model's discretization accounts for it, and physics
    cannot be read from it on this mesh.

    Returns None where it does not apply (not the fsi model, explicit element sizes, no
    finer preset); a record with ``failed`` (the reason) where the finer solve failed.
    """
    from bayescalib.config import validate
    from bayescalib.models.forward import solve_points
    from bayescalib.models.fsi.model import finer_preset

    fm = ctx.fm
    if fm.get("type") != "fsi":
        return None
    fsi = validate(fm.get("fsi") or {}, "fsi")
    mesh = fsi["mesh"]
    finer = finer_preset(int(fsi["geometry"]["dim"]), mesh["preset"])
    if finer is None or any(mesh[k] is not None for k in ("h_interface", "h_solid", "h_bulk")):
        return None
    at = lin.base_point
    fine_fm = {**fm, "fsi": {**(fm.get("fsi") or {}),
                             "mesh": {**((fm.get("fsi") or {}).get("mesh") or {}),
                                      "preset": finer}}}
    # no warm start: the study's state is on another mesh
    run = solve_points(fine_fm, [at], [ctx.work / "base" / "discretization" / f"{finer}.h5"])[0]
    out: dict[str, Any] = {"preset": mesh["preset"], "finer_preset": finer, "at": at}
    if not run.ok:
        out["failed"] = run.reason
        return out
    there = model_interfaces(run, ctx.n_snap)
    moved, shifts = zip(*(corrected_for_mesh(n, h, f) for n, h, f
                          in zip(ctx.nodes, lin.reference, there, strict=True)), strict=True)
    e_all = np.concatenate(shifts)
    after = ctx.predictive_check(list(moved), draws["curves"], _recheck_sigma(ctx, check),
                                 int(ctx.settings["seed"]))
    out.update(error_rms_mm=float(np.sqrt(np.mean(e_all ** 2))),
               error_max_mm=float(np.max(np.abs(e_all))),
               error_mean_mm=float(np.mean(e_all)), check_after=after.to_json())
    out["explains"] = bool(explains_mismatch(out["check_after"], check))
    log.info("discretization check: the %s mesh's prediction differs from the %s mesh's by "
             "%.3g mm RMS at the observed nodes; corrected for it, the check %s",
             finer, mesh["preset"], out["error_rms_mm"],
             "explains the mismatch" if out["explains"] else "does not explain it")
    return {**out, "_check": after}  # the check itself for the figures, not the record


def _zero_load_label(fm: Mapping[str, Any], labels: Sequence[str]) -> str | None:
    """Label of the snapshot observed at zero load (loading factor 0), if any."""
    from bayescalib.models.forward import loading_factors

    factors = loading_factors(fm)
    if len(factors) != len(labels):
        return None
    return next((lab for f, lab in zip(factors, labels, strict=True) if float(f) == 0.0), None)


def _bias(summary: Mapping[str, Any], parameters: Sequence[Mapping[str, Any]]) -> dict | None:
    truth = {p["name"]: p.get("ground_truth") for p in parameters}
    if any(v is None for v in truth.values()):
        return None
    mean = summary["mean"]
    return {n: {"posterior_mean": float(mean[n]), "truth": float(t),
                "relative_error": float(abs(mean[n] - t) / abs(t)) if t else float(abs(mean[n]))}
            for n, t in truth.items() if n in mean}


def _refit(ctx: DiagnosisContext, lin: Linearization, check) -> dict[str, Any]:
    """The re-fit test (:func:`~bayescalib.diagnosis.attribution.refit_test`): whether a
    step of the base parameters alone absorbs the mismatch, with the re-fitted point and
    whether it lies in the box."""
    from bayescalib.diagnosis.attribution import refit_test

    names = ctx.names
    refit = refit_test(lin.r, lin.J, np.full(len(lin.r), check.sigma**2))
    refit["step"] = dict(zip([names[i] for i in lin.fd], refit["step"], strict=True))
    refit["parameters"] = {n: float(lin.theta[names.index(n)] + d)
                           for n, d in refit["step"].items()}
    refit["in_bounds"] = bool(all(lin.lo[names.index(n)] <= x <= lin.hi[names.index(n)]
                                  for n, x in refit["parameters"].items()))
    return refit


def _confirm_extension(ctx: DiagnosisContext, cal: dict[str, Any], model: CheckedModel):
    """Step 5 for one extension: the predictive check at solved draws of its posterior,
    the round that represents it (:func:`_better_confirmed_round`) and the check
    reported (:func:`_reported_predictive_check`). An extended posterior where the
    forward model does not solve (the surrogate interpolates over failed points) cannot
    be confirmed: recorded, not fatal.

    Returns the calibration (of the round kept), the check reported (None: none solved),
    its failed draws, why it failed (None), the rounds re-checked and the reported
    check's draws (their source)."""
    try:
        after, n_fail_after, _ = _predictive_check_at_draws(
            ctx, model, cal["particles"], model.tag, int(ctx.settings["seed"]))
        check_failed = None
    except PredictiveCheckError as exc:
        log.warning("%s", exc)
        after, n_fail_after, check_failed = None, int(ctx.settings["n_draws"]), str(exc)
    cal, after, n_fail_after, rechecked = _better_confirmed_round(ctx, cal, after,
                                                                  n_fail_after, model)
    after, n_fail_after, after_source = _reported_predictive_check(
        ctx, cal, after, n_fail_after, rechecked, model)
    if after is None and check_failed is None:
        check_failed = after_source.get("failed")
    return cal, after, n_fail_after, check_failed, rechecked, after_source


def _calibrate_extension(ctx: DiagnosisContext, base: BaseCalibration, sigma: float | None,
                         group: list[CandidateSpec]) -> dict[str, Any]:
    """Calibrate base + ``group`` and re-check it with real solves (steps 4-5); the
    extension's record, not yet judged (:func:`judge_extensions`). ``sigma``: the noise
    sd given to its predictive checks (:func:`_recheck_sigma`)."""
    from bayescalib.inference.active import history_table

    cfg = ctx.settings
    name = joint_name(group)
    n_new = int(cfg["n_train"] or ctx.active["n_initial"])
    max_new = int(cfg["max_solves"] or ctx.active["max_solves"])
    cal = extended_calibration(
        group, fm=ctx.fm, parameters=ctx.parameters, base_training=ctx.training_path,
        n_new=n_new * len(group), max_new=max_new * len(group),
        seed=int(cfg["seed"]) + 1, active=ctx.active,
        workdir=ctx.work / name.replace(" + ", "+"), **ctx.chain())
    model = CheckedModel(name.replace(" + ", "+"), ctx.targets + [c.target for c in group],
                         {k: val for c in group for k, val in c.switches.items()}, sigma)
    cal, after, n_fail_after, check_failed, rechecked, after_source = _confirm_extension(
        ctx, cal, model)
    post = cal["posterior"]
    phi = {c.name: {"mean": float(post["mean"][f"phi_{c.name}"]),
                    "std": float(post["std"][f"phi_{c.name}"]),
                    "interval": post["intervals"].get(f"phi_{c.name}"),
                    "prior": list(c.prior), "unit": c.unit} for c in group}
    one = phi[group[0].name] if len(group) == 1 else None
    return {
        "candidate": name, "members": [c.name for c in group],
        "summary": "; ".join(c.summary for c in group),
        "unit": group[0].unit if one else "-",
        "log_evidence": cal["log_evidence"],
        "log_bayes_factor": cal["log_evidence"] - base.log_evidence,
        "phi": phi,
        "phi_mean": one["mean"] if one else None,
        "phi_std": one["std"] if one else None,
        "phi_prior": one["prior"] if one else None,
        "phi_interval": one["interval"] if one else None,
        "n_new_solves": cal["n_new"], "n_reused": cal["n_reused"],
        "n_failed": cal["n_failed"], "converged": cal["converged"],
        "reason": cal["reason"], "rounds": history_table(cal["rounds"]),
        "n_failed_draws_after": int(n_fail_after),
        "check_after": None if after is None else after.to_json(),
        "check_after_failed": check_failed,
        "posterior": {k: post[k] for k in ("names", "mean", "std", "map")},
        "bias_after": _bias(post, ctx.parameters),
        "particles": cal["particles"],
        "reported_round": cal.get("reported_round"),
        "rechecked_rounds": rechecked,
        "check_after_draws": after_source,
        "_check": after,
    }


def _extension_groups(ctx: DiagnosisContext,
                      found: Attribution) -> list[tuple[list[CandidateSpec], str]]:
    """The extended models to calibrate (step 4): each of the ``n_extend`` best-ranked
    identifiable candidates of plausible magnitude (the selected first), and those the
    attribution selected together as one model."""
    attr = found.result
    ranked = [row["candidate"] for row in attr["ranking"]
              if row["identifiable_fraction"] > MIN_IDENTIFIABLE and row["phi_hat_plausible"]]
    singles = list(dict.fromkeys(attr["selected"] + ranked))[: int(ctx.settings["n_extend"])]
    by_name = {c.name: c for c in found.cands}
    groups = [([by_name[n]], "ranking") for n in singles]
    if len(attr["selected"]) > 1:  # effects found together are modelled together
        groups.append(([by_name[n] for n in attr["selected"]], "attribution"))
    return groups


def _screen(ctx: DiagnosisContext, check, found: Attribution,
            registration: dict | None) -> Screening:
    """The re-fit test and the verdict before any modelling; no candidate is modelled
    when the check passes (unless ``diagnose.force_extend``), when the base parameters
    absorb the mismatch, or when a misregistration explains it and the attribution
    selected no physics."""
    cfg, selected = ctx.settings, found.result["selected"]
    refit = _refit(ctx, found.lin, check)
    screen = decide_verdict(check.adequate, selected, refit, float(cfg["alpha"]),
                            registration=registration, untestable=sorted(found.failed),
                            single_snapshot=len(ctx.obs.labels) == 1)
    extend = ((not check.adequate and screen != ABSORBED
               and not (screen == MISREGISTERED and not selected))
              or bool(cfg["force_extend"])) and int(cfg["n_extend"]) > 0
    return Screening(refit, screen, extend)


def _extend(ctx: DiagnosisContext, base: BaseCalibration, check, found: Attribution,
            registration: dict | None, screening: Screening) -> Extensions:
    """Steps 4-5: calibrate the extended models the screening calls for, check each with
    real solves and judge them (:func:`model_extensions`); the registered observations'
    re-check is judged against the same reference noise."""
    calibrate = functools.partial(_calibrate_extension, ctx, base, _recheck_sigma(ctx, check))
    extended, noise_ref, joint = model_extensions(
        _extension_groups(ctx, found) if screening.extend else [], calibrate, check,
        registration_after=(registration or {}).get("check_after"),
        max_effects=int(ctx.settings["max_effects"]),
        joint_when=str(ctx.settings["joint_of_singles"]))
    if registration is not None and registration.get("check_after") is not None:
        registration["explains"] = bool(registration["first_order"] and explains_mismatch(
            registration["check_after"], check, noise_ref))
    return Extensions(extended, noise_ref, joint)


def _decide(ctx: DiagnosisContext, check, found: Attribution, registration: dict | None,
            screening: Screening, extensions: Extensions,
            discretization: Mapping[str, Any] | None = None) -> Decision:
    """Choose a model (:func:`choose_extension`), set aside by name every candidate no
    extension contains (:func:`set_aside_candidates`) and decide the verdict
    (:func:`decide_verdict`; when the mesh's own error explains the mismatch,
    :func:`_discretization_check`, the verdict says so: :data:`DISCRETIZED` without a
    chosen extension, else beside it)."""
    cfg, attr, extended = ctx.settings, found.result, extensions.extended
    best = choose_extension(extended)
    # a candidate implausible alone but selected beside another is calibrated within its
    # range only: unless that extension is chosen, it is named as set aside too
    plausible = {row["candidate"]: row["phi_hat_plausible"] for row in attr["ranking"]}
    within: dict[str, list[str]] = {}
    for e in extended:
        for m in e["members"]:
            if not plausible.get(m, True) and (best is None or m not in best["members"]):
                within.setdefault(m, []).append(e["candidate"])
    # a significant candidate left out by n_extend matters while no extension explains it
    aside = [] if check.adequate else set_aside_candidates(
        attr["ranking"], found.cands, found.failed, threshold=float(attr["threshold"]),
        r2_min=float(cfg["r2_min"]),
        calibrated={m for e in extended for m in e["members"]} - set(within),
        n_extend=int(cfg["n_extend"]) if screening.extend and best is None else None,
        user_candidates=bool(cfg["candidates"]), within=within)
    chosen = best["candidate"] if best is not None else "base"
    verdict = decide_verdict(check.adequate, attr["selected"], screening.refit,
                             float(cfg["alpha"]), chosen=None if best is None else chosen,
                             modelled=bool(extended), registration=registration,
                             untestable=sorted(found.failed),
                             single_snapshot=len(ctx.obs.labels) == 1, set_aside=aside)
    verdict = with_discretization(verdict, best is not None, discretization)
    return Decision(screening, extensions, aside, chosen, verdict)


def _diagnosis_record(ctx: DiagnosisContext, base: BaseCalibration, check,
                      n_failed_draws: int, found: Attribution, registration: dict | None,
                      decision: Decision, discretization: Mapping[str, Any] | None = None
                      ) -> dict[str, Any]:
    """The ``diagnosis.json`` content (plain values), its plain words included."""
    attr, obs = found.result, ctx.obs
    out = {
        "verdict": decision.verdict,
        "dim": ctx.dim,
        "screening_verdict": decision.screening.verdict,
        "attribution_verdict": attr["verdict"],
        "check": check.to_json(),
        "n_draws": int(ctx.settings["n_draws"]), "n_failed_draws": int(n_failed_draws),
        "attribution": {k: attr[k] for k in ("ranking", "selected", "explained", "threshold",
                                             "steps")},
        "refit": decision.screening.refit,
        "registration": registration,
        "discretization": (None if discretization is None else
                           {k: v for k, v in discretization.items() if k != "_check"}),
        "zero_load_snapshot": _zero_load_label(ctx.fm, obs.labels),
        "failed_signatures": found.failed,
        "noise_reference_mm": decision.extensions.noise_reference,
        "signature_attempts": found.attempts,
        "posterior_mean": dict(zip(ctx.names, map(float, found.lin.theta), strict=True)),
        "extended": [{k: val for k, val in e.items() if k != "_check"}
                     for e in decision.extensions.extended],
        "joint_of_singles": decision.extensions.joint,
        "set_aside": decision.set_aside,
        "chosen_model": decision.chosen,
        "bias_before": _bias(base.summary, ctx.parameters),
        "base_calibration": base.design,
        "hidden_truth": obs.meta.get("hidden") or None,
        "hidden_misregistration": obs.meta.get("misregistration") or None,
        "observed_nodes": {"n_observed": ctx.n_observed,
                           "n_used": [len(n) for n in ctx.nodes],
                           "spacing_mm": float(ctx.noise_lag_mm
                                               if ctx.surface_spacing_mm is None
                                               else ctx.surface_spacing_mm),
                           "noise_lag_mm": float(ctx.noise_lag_mm)},
        "units": "lengths mm; phi in the candidate's unit; registration shifts mm, "
                 "rotation rad, scale relative",
    }
    out["plain_words"] = plain_words(out)
    return out


# ----------------------------------------------------------------------------- stage
def run_diagnosis(
    *,
    fm: Mapping[str, Any],
    parameters: Sequence[Mapping[str, Any]],
    observations: Mapping[str, Any],
    measure_name: str,
    measure: Mapping[str, Any],
    likelihood: Mapping[str, Any],
    surrogate: Mapping[str, Any],
    smc_cfg: Mapping[str, Any],
    posterior_cfg: Mapping[str, Any],
    diagnose: Mapping[str, Any],
    active: Mapping[str, Any],
    design: Mapping[str, Any],
    particles_path: str | Path,
    training_path: str | Path,
    posterior_path: str | Path,
    obs_path: str | Path,
    outdir: str | Path,
    workers: int = 1,
    warm_start: str | Path | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Run the diagnosis stage (see the module docstring).

    Returns
    -------
    diagnosis : dict
        The ``diagnosis.json`` content (plain values).
    checks : dict
        :class:`~bayescalib.diagnosis.residuals.PredictiveCheck` of the base model
        (``"base"``) and of each extended model (by candidate), for the figures.

    ``active`` is the study's validated ``design.active`` section (the extended
    calibrations use it); ``design`` the design block of the study's calibration
    (:func:`bayescalib.stages.summary.design_summary`: strategy, solves, converged, reason).

    Solves and extended calibrations are kept under ``outdir`` and reused.
    """
    ctx = DiagnosisContext.build(
        diagnose=diagnose, observations=observations, obs_path=obs_path, outdir=outdir,
        warm_start=warm_start, fm=fm, parameters=parameters, measure_name=measure_name,
        measure=measure, likelihood=likelihood, surrogate=surrogate, smc_cfg=smc_cfg,
        posterior_cfg=posterior_cfg, active=active, training_path=training_path,
        workers=workers)
    # 0: the study's calibration, as summary.json reports it
    base = BaseCalibration.read(particles_path, posterior_path, design)
    # 1-2: detect and locate (the predictive check of the base model)
    check, n_failed_draws, draws = _predictive_check_at_draws(
        ctx, CheckedModel("base", ctx.targets, {}, ctx.sigma), base.particles, "base",
        int(ctx.settings["seed"]))
    log.info("predictive check: adequate=%s p=%s", check.adequate, check.p_values)
    # 3: attribute to candidate physics, and test a misregistration (not physics)
    found = _attribute(ctx, base.summary["mean"], check, draws)
    # is the mismatch the mesh's own error? (the posterior mean on the next finer mesh)
    discretization = (None if check.adequate or not ctx.settings["discretization_check"]
                      else _discretization_check(ctx, check, draws, found.lin))
    # (a rigid misregistration is tested in 2D only: its signatures are in-plane moves)
    registration = (_registration(ctx, found.lin, check, draws)
                    if ctx.settings["registration"] and ctx.dim == 2 else None)
    # 4-5: extend (when the screening calls for it) and check the extensions with real
    # solves, then decide
    screening = _screen(ctx, check, found, registration)
    extensions = _extend(ctx, base, check, found, registration, screening)
    decision = _decide(ctx, check, found, registration, screening, extensions, discretization)
    # 6: report
    out = _diagnosis_record(ctx, base, check, n_failed_draws, found, registration, decision,
                            discretization)
    checks = {"base": check, **{e["candidate"]: e["_check"] for e in extensions.extended
                                if e["_check"] is not None}}
    if discretization is not None and discretization.get("_check") is not None:
        checks["discretization"] = discretization["_check"]
    return out, checks


def explains_mismatch(after: Mapping[str, Any], base: Any,
                      sigma: float | None = None) -> bool:
    """Whether a re-check (real solves) explains the base model's mismatch.

    ``after`` is a :meth:`PredictiveCheck.to_json` of the repaired model (an extension
    or registered observations), ``base`` the base model's :class:`PredictiveCheck`. It
    explains the mismatch when it fits better than the base model *and* its check
    passes or its residual RMS is within :data:`EXPLAINED_RMS` times the noise sd: a
    smaller residual alone (e.g. 9.3 -> 8.8 um against 1.5 um noise) is an extension
    absorbing a little of a mismatch it does not explain. The RMS rule tells only where
    the base model's own residual is beyond it: a small, local mismatch (the base at
    1.48 um against 1 um noise, its check failed) is explained only by a repair whose
    check passes, not by one that trims the RMS to 1.43 um and still fails its check.

    ``sigma`` (mm): the noise sd to judge against (:func:`reference_noise`); default
    the re-check's own, ``after["sigma_mm"]``.
    """
    rms = float(after["residual_rms_mm"])
    noise = float(after["sigma_mm"]) if sigma is None else float(sigma)
    if not rms < base.rms:
        return False
    if bool(after["adequate"]):
        return True
    return rms <= EXPLAINED_RMS * noise < base.rms


def reference_noise(base: Any, afters: Sequence[Mapping[str, Any] | None]) -> float:
    """The noise sd (mm) every re-check is judged against (:func:`explains_mismatch`).

    Given noise (``base.sigma_source == "given"``) is the base check's. Estimated noise
    (images) is estimated by each check from its own residual's rough part, which a
    model's unexplained mismatch inflates (a sharp corner of the residual reads as
    noise): a repair that fits worse would get a larger noise and pass the
    ``EXPLAINED_RMS`` rule more easily (seen: registered observations at 3.70 um
    "explained" against their own 2.99 um, while the extension's residual gave 2.34 um).
    The data have one noise level, so the smallest estimate
    among the base check and the re-checks ``afters`` (``to_json`` dicts; None skipped)
    is used: the least contaminated one.
    """
    if getattr(base, "sigma_source", "given") == "given":
        return float(base.sigma)
    return float(min([float(base.sigma)] + [float(a["sigma_mm"]) for a in afters
                                             if a is not None]))


def judge_extensions(extended: Sequence[dict[str, Any]], base: Any,
                     registration_after: Mapping[str, Any] | None = None) -> float:
    """Judge each calibrated extension against the base model, in place.

    Sets ``improves`` (its real solves fit better than the base model's), ``explains``
    (:func:`explains_mismatch` against the one noise level of :func:`reference_noise`,
    over the base check, the registered observations' re-check ``registration_after``
    and every extension's) and ``surrogate_consistent`` (a log Bayes factor above
    ``ln 3`` that the real solves do not confirm is the surrogate's, flagged).

    Returns
    -------
    float
        The reference noise sd (mm).
    """
    noise_ref = reference_noise(base, [registration_after]
                                + [e["check_after"] for e in extended])
    for e in extended:
        after = e["check_after"]
        e["improves"] = bool(after is not None
                             and float(after["residual_rms_mm"]) < float(base.rms))
        e["explains"] = bool(after is not None and explains_mismatch(after, base, noise_ref))
        # the Bayes factor comes from GP surrogates: flag it when the real solves at the
        # extended posterior do not fit better than the base model
        e["surrogate_consistent"] = bool(e["log_bayes_factor"] <= LN_BF_MIN or e["improves"])
    return noise_ref


def fits_better(e: Mapping[str, Any]) -> bool:
    """Whether a judged extension fits significantly better than the base model: its
    log Bayes factor exceeds ``ln 3`` (:data:`LN_BF_MIN`, the evidence the choice of a
    model asks for) and its real solves fit better (``improves``)."""
    return bool(e["log_bayes_factor"] > LN_BF_MIN and e["improves"])


def choose_extension(extended: Sequence[Mapping[str, Any]]) -> Mapping[str, Any] | None:
    """The chosen extension: among those whose real solves explain the mismatch, the
    one with the largest log Bayes factor, if that exceeds ``ln 3``; None: the base
    model stays."""
    confirmed = [e for e in extended if e["explains"] and e["log_bayes_factor"] > LN_BF_MIN]
    return max(confirmed, key=lambda e: e["log_bayes_factor"], default=None)


def joint_of_singles(extended: Sequence[Mapping[str, Any]], *, max_effects: int,
                     when: str) -> dict[str, Any] | None:
    """The joint model to calibrate after the single extensions, if any.

    Two effects present at once can each take part of the mismatch: each single
    extension then fits significantly better than the base model (:func:`fits_better`)
    and none explains the mismatch alone, while the linearized attribution, which sees
    each effect through its first-order signature only, may not have selected them
    together. Then the joint model of the best of them (largest log Bayes factors, up
    to ``max_effects``) is calibrated too, and chosen or not by evidence and fit like
    any other (:func:`choose_extension`).

    Parameters
    ----------
    extended
        The judged extensions so far (:func:`judge_extensions`); singles have one member.
    max_effects
        Most effects in one model (``diagnose.max_effects``).
    when
        ``diagnose.joint_of_singles``: ``"unexplained"`` (none of them explains the
        mismatch alone), ``"always"`` (also when one does: a second effect may sit beside
        one that passes the check) or ``"never"``.

    Returns
    -------
    dict or None
        ``candidate`` (:func:`~bayescalib.diagnosis.extended.joint_name` order),
        ``members``, ``why`` (``"none explains alone"`` or ``"one explains alone"``) and
        ``singles`` (each single that fits better: ``candidate``, ``log_bayes_factor``,
        ``residual_rms_mm``, ``explains``, best first); None when no joint model is due
        (fewer than two fit better, one explains alone under ``"unexplained"``, or that
        joint model was calibrated already).
    """
    if when == "never" or max_effects < 2:
        return None
    better = sorted((e for e in extended if len(e["members"]) == 1 and fits_better(e)),
                    key=lambda e: -float(e["log_bayes_factor"]))
    if len(better) < 2:
        return None
    alone = any(e["explains"] for e in better)
    if alone and when != "always":
        return None
    members = [e["members"][0] for e in better[:max_effects]]
    if any(set(e["members"]) == set(members) for e in extended):
        return None  # the attribution selected them together: calibrated already
    return {"candidate": " + ".join(members), "members": members,
            "why": "one explains alone" if alone else "none explains alone",
            "singles": [{"candidate": e["candidate"],
                         "log_bayes_factor": float(e["log_bayes_factor"]),
                         "residual_rms_mm": float(e["check_after"]["residual_rms_mm"]),
                         "explains": bool(e["explains"])} for e in better]}


def model_extensions(groups: Sequence[tuple[Sequence[CandidateSpec], str]], calibrate,
                     base: Any, *, registration_after: Mapping[str, Any] | None,
                     max_effects: int, joint_when: str
                     ) -> tuple[list[dict[str, Any]], float, dict[str, Any] | None]:
    """Calibrate the extended models and judge them (steps 4-5).

    Each group (its candidates and why it is calibrated: ``"ranking"`` for a single
    candidate of the ranking, ``"attribution"`` for those the attribution selected
    together) is calibrated by ``calibrate(candidates) -> record`` and judged
    (:func:`judge_extensions`). When the single extensions call for it
    (:func:`joint_of_singles`, ``joint_when``: ``diagnose.joint_of_singles``), the joint
    model of the best of them is calibrated next
    (origin ``"joint of singles"``) and every extension is judged again (the noise
    reference may change with its re-check).

    Returns
    -------
    extended : list of dict
        The records of ``calibrate`` with ``origin`` and the judgement.
    noise_ref : float
        The reference noise sd, mm.
    joint : dict or None
        The joint model calibrated after the singles (:func:`joint_of_singles`).
    """
    extended = []
    for group, origin in groups:
        extended.append({**calibrate(list(group)), "origin": origin})
    noise_ref = judge_extensions(extended, base, registration_after)
    joint = joint_of_singles(extended, max_effects=max_effects, when=joint_when)
    if joint is not None:
        by_name = {c.name: c for group, _ in groups for c in group}
        log.info("%s each fit better than the base model and %s: calibrating %s",
                 ", ".join(joint["members"]), joint["why"], joint["candidate"])
        extended.append({**calibrate([by_name[n] for n in joint["members"]]),
                         "origin": "joint of singles"})
        noise_ref = judge_extensions(extended, base, registration_after)
    return extended, noise_ref, joint


def _config_key(name: str, cands: Sequence[CandidateSpec], user_candidates: bool) -> str:
    """Where the prior range of a candidate is set."""
    if user_candidates:
        return f"diagnose.candidates[{[c.name for c in cands].index(name)}].prior"
    return f"diagnose.priors.{name}"


def _round_out(x: float, up: bool) -> float:
    """``x`` rounded outward (up or down) to two significant digits."""
    if x == 0.0:
        return 0.0
    f = 10.0 ** (math.floor(math.log10(abs(x))) - 1)
    return float((math.ceil(x / f) if up else math.floor(x / f)) * f)


def widened_range(prior: Sequence[float], estimate: float) -> list[float]:
    """A prior range widened to hold ``estimate`` with room to spare: the bound it
    passes moved to 1.5 times the estimate's distance from the other bound, rounded
    outward to two significant digits."""
    lo, hi = (float(x) for x in prior)
    if estimate > hi:
        return [lo, _round_out(lo + 1.5 * (estimate - lo), up=True)]
    if estimate < lo:
        return [_round_out(hi - 1.5 * (hi - estimate), up=False), hi]
    return [lo, hi]


def set_aside_candidates(ranking: Sequence[Mapping[str, Any]], cands: Sequence[CandidateSpec],
                         failed: Mapping[str, str], *, threshold: float, r2_min: float,
                         calibrated: set[str], n_extend: int | None,
                         user_candidates: bool,
                         within: Mapping[str, Sequence[str]] | None = None
                         ) -> list[dict[str, Any]]:
    """Every candidate the diagnosis set aside, each with what the user could do.

    A candidate that no extended model contains is set aside, by ``reason``:

    * ``"not identifiable"``: at most :data:`MIN_IDENTIFIABLE` of its signature is
      beyond what the base parameters can mimic; these data cannot tell it from them
      (advice: a snapshot at another loading);
    * ``"implausible magnitude"``: significant (p below ``threshold``, the attribution's
      Bonferroni level), but its one-step estimate lies outside its plausible range by
      more than half the range's width (advice: widen the prior to ``suggested_range``
      if such a magnitude is possible, :func:`widened_range`);
    * ``"not calibrated"``: significant, plausible and identifiable, but ranked below the
      ``n_extend`` candidates calibrated (advice: raise ``diagnose.n_extend``); only
      where it matters, when extensions were calibrated and none explains the mismatch
      (the caller passes ``n_extend``; None: none of these);
    * ``"not testable"``: its signature solves failed at every step tried (``failed``).

    ``large_share`` marks a significant one that alone explains at least ``r2_min`` of
    the mismatch beyond noise (to first order): the verdict never says that no
    candidate explains the mismatch while one of those is set aside.

    ``within``: candidates implausible alone that the attribution selected beside
    another (their estimate beside it lies in range), each with the extensions that
    hold them, none chosen. Calibrated within their prior range only, they are set
    aside as ``"implausible magnitude"`` too, with those extensions in
    ``calibrated_within_range_in`` (a truth beyond the range is out of their reach).

    Returns
    -------
    list of dict
        In the ranking's order (the untestable last): ``candidate``, ``summary``,
        ``unit``, ``reason``, ``rank``, ``p_value``, ``explained_fraction``,
        ``identifiable_fraction``, ``estimate`` (the one-step ``phi_hat``), ``range``
        (its prior), ``large_share``, ``config_key`` (where its range is set),
        ``advice``; ``suggested_range`` for an implausible magnitude, ``failure`` for
        an untestable one.
    """
    by_name = {c.name: c for c in cands}
    out = []
    for rank, row in enumerate(ranking, start=1):
        name = row["candidate"]
        if name in calibrated:
            continue
        c = by_name[name]
        significant = float(row["p_value"]) < threshold
        est = float(row["phi_hat"])
        key = _config_key(name, cands, user_candidates)
        entry = {"candidate": name, "summary": c.summary, "unit": c.unit, "rank": rank,
                 "p_value": float(row["p_value"]),
                 "explained_fraction": float(row["explained_fraction"]),
                 "identifiable_fraction": float(row["identifiable_fraction"]),
                 "estimate": est, "range": [float(x) for x in c.prior],
                 "large_share": bool(significant
                                     and float(row["explained_fraction"]) >= r2_min),
                 "config_key": key}
        if float(row["identifiable_fraction"]) <= MIN_IDENTIFIABLE:
            out.append({**entry, "reason": "not identifiable", "advice": (
                "a snapshot at another loading (forward_model.loadings, with its "
                "observation) could tell it apart from the base parameters")})
        elif significant and not row["phi_hat_plausible"]:
            wide = widened_range(c.prior, est)
            if within and name in within:
                entry["calibrated_within_range_in"] = list(within[name])
            out.append({**entry, "reason": "implausible magnitude", "suggested_range": wide,
                        "advice": (
                            f"if a magnitude of {est:.3g}{_unit(c.unit)} is physically "
                            f"possible, widen its prior ({key}: [{wide[0]:.3g}, "
                            f"{wide[1]:.3g}]) and rerun the diagnosis; if not, it only "
                            "mimics the mismatch, and a snapshot at another loading could "
                            "tell them apart")})
        elif significant and n_extend is not None:
            out.append({**entry, "reason": "not calibrated", "advice": (
                f"raise diagnose.n_extend (now {n_extend}) to calibrate it")})
    for name, why in failed.items():
        c = by_name[name]
        out.append({"candidate": name, "summary": c.summary, "unit": c.unit, "rank": None,
                    "p_value": None, "explained_fraction": None,
                    "identifiable_fraction": None, "estimate": None,
                    "range": [float(x) for x in c.prior], "large_share": False,
                    "config_key": _config_key(name, cands, user_candidates),
                    "reason": "not testable", "failure": why, "advice": NOT_TESTABLE_ADVICE})
    return out


def _unit(unit: str) -> str:
    """`` <unit>``, or nothing for a dimensionless ``-``."""
    return "" if unit in ("", "-") else f" {unit}"


def decide_verdict(adequate: bool, selected: Sequence[str], refit: Mapping[str, Any],
                   alpha: float, *, chosen: str | None = None, modelled: bool = False,
                   registration: Mapping[str, Any] | None = None,
                   untestable: Sequence[str] = (), single_snapshot: bool = False,
                   set_aside: Sequence[Mapping[str, Any]] = ()) -> str:
    """The diagnosis verdict, in order of precedence.

    1. ``"no significant mismatch"``: the predictive check passes.
    2. ``"mismatch explained by <chosen>"``: an extended model was calibrated and its
       real solves explain the mismatch (:func:`explains_mismatch`); the verdict and the
       chosen model never disagree. When a misregistration explains it as well, the
       verdict names both and says that the data cannot tell them apart.
    3. ``"mismatch explained by a misregistration ..."``: a rigid misplacement of the
       observed interfaces explains it, confirmed with real solves (registered
       observations against the jointly re-fitted base model). "Not physics" only with
       two snapshots or more (``single_snapshot`` False): one misplacement for every
       loading, where a flow-driven effect changes with the load. From a single
       snapshot the verdict is :data:`MISREGISTERED_OR_PHYSICS`.
    4. ``"mismatch attributed to <selected> (not modelled)"``: the linearized
       attribution selected candidates and no extension was calibrated.
    5. ``"mismatch absorbed by the base parameters; ..."``: the re-fit test passes
       (``refit["p_value"] >= alpha``) at a re-fitted point inside the design box
       (``refit["in_bounds"]``; a step that leaves the box is outside the reach of
       the linearization and of the prior, so it proves nothing).
    6. ``"mismatch located; not explained by the candidates tested (set aside: growth
       would explain 76 % at a magnitude outside its plausible range ...)"`` when a
       candidate set aside (:func:`set_aside_candidates`, ``large_share``) alone explains
       most of it to first order; else ``"mismatch located; no tested candidate
       explains it (not testable: ...)"`` when some candidates could not be evaluated
       (their signature solves failed), else ``"mismatch located; no candidate
       explains it"``. "No candidate explains it" is never said while a candidate that
       could was set aside or not tested.
    """
    misregistered = registration is not None and bool(registration.get("explains"))
    if adequate:
        return "no significant mismatch"
    if chosen and misregistered:
        return (f"mismatch explained by {chosen} or by a misregistration of the observed "
                "interfaces (the data cannot tell them apart)")
    if chosen:
        return "mismatch explained by " + chosen
    if misregistered:
        return MISREGISTERED_OR_PHYSICS if single_snapshot else MISREGISTERED
    if selected and not modelled:
        return "mismatch attributed to " + " + ".join(selected) + " (not modelled)"
    if refit.get("in_bounds", False) and float(refit["p_value"]) >= alpha:
        return ABSORBED
    large = [e for e in set_aside if e.get("large_share")]
    if large:
        notes = ["set aside: " + "; ".join(
            f"{e['candidate']} would explain {100 * float(e['explained_fraction']):.0f} % "
            + _SET_ASIDE_SHORT[e["reason"]] for e in large)]
        if untestable:
            notes.append("not testable: " + ", ".join(untestable))
        return "mismatch located; not explained by the candidates tested (" \
            + "; ".join(notes) + ")"
    if untestable:
        return ("mismatch located; no tested candidate explains it (not testable: "
                + ", ".join(untestable) + ")")
    return "mismatch located; no candidate explains it"


#: why a candidate that would explain most of the mismatch was set aside, for the verdict
_SET_ASIDE_SHORT = {
    "implausible magnitude": "at a magnitude outside its plausible range",
    "not identifiable": "but cannot be told apart from the base parameters",
    "not calibrated": "but was not calibrated (diagnose.n_extend)",
}


def _phi_words(e: Mapping[str, Any]) -> str:
    return ", ".join(f"phi_{n} = {p['mean']:.3g} +- {p['std']:.2g} {p['unit']}"
                     for n, p in e["phi"].items())


def _p_words(p: float) -> str:
    return "p < 1e-16" if p < 1e-16 else f"p = {p:.3g}"


def _registration_words(reg: Mapping[str, Any]) -> str:
    est = reg["estimate"]
    parts = []
    if "shift_x" in est or "shift_y" in est:
        parts.append(f"shifted by ({1e3 * est.get('shift_x', 0.0):.2f}, "
                     f"{1e3 * est.get('shift_y', 0.0):.2f}) um")
    if "rotation" in est:
        parts.append(f"rotated by {1e3 * est['rotation']:.2f} mrad")
    if "scale" in est:
        parts.append(f"scaled by {100 * est['scale']:+.2f} %")
    return ", ".join(parts)


def _noise_words(chk: Mapping[str, Any]) -> str:
    """How the check's replicates drew their noise, in words."""
    nm = (chk.get("noise_model") or {}).get("name", "gaussian")
    if nm == "bootstrap":
        return "noise resampled from the residual's rough part"
    return "independent Gaussian noise per node"


def _rms_after_words(e: Mapping[str, Any]) -> str:
    """Where an extension's reported RMS comes from and how it varies over its draws."""
    ca = e["check_after"]
    src = e.get("check_after_draws") or {}
    sp = ca.get("residual_rms_spread")
    n_ok = int(src.get("n_draws", 0)) - int(src.get("n_failed", 0))
    if src.get("draws") == "fresh":
        words = (f"RMS from {n_ok} fresh posterior draws solved for this report only (seed "
                 f"{src['seed']}; the draws that chose the round gave "
                 f"{1e3 * src['selection_rms_mm']:.2f} um)")
    else:
        words = f"RMS from the check's {n_ok} posterior draws"
    if sp:
        words += (f"; per draw median {1e3 * sp['per_draw_median_mm']:.2f} um (16-84 %: "
                  f"{1e3 * sp['per_draw_q16_mm']:.2f}-{1e3 * sp['per_draw_q84_mm']:.2f} um), "
                  f"bootstrap over draws {1e3 * sp['bootstrap_q16_mm']:.2f}-"
                  f"{1e3 * sp['bootstrap_q84_mm']:.2f} um")
    return words


def _ordinal(k: int) -> str:
    return f"{k}{'th' if 10 <= k % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(k % 10, 'th')}"


def _names(names: Sequence[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _discretization_words(disc: Mapping[str, Any], chk: Mapping[str, Any]) -> str:
    """The discretization check (:func:`_discretization_check`) in plain words."""
    fine, here = disc["finer_preset"], disc["preset"]
    if disc.get("failed"):
        return (f"The posterior mean could not be solved on the {fine} mesh to compare with "
                f"the {here} mesh ({disc['failed']}): the mesh's own error is not known.")
    ca = disc["check_after"]
    said = (f"The forward model's prediction at the posterior mean moves by "
            f"{1e3 * disc['error_rms_mm']:.2f} um RMS (up to {1e3 * disc['error_max_mm']:.2f} "
            f"um) from the {here} mesh to the {fine} mesh; with the observations corrected "
            f"for that difference, the residual RMS is {1e3 * chk['residual_rms_mm']:.2f} -> "
            f"{1e3 * ca['residual_rms_mm']:.2f} um")
    if disc["explains"]:
        return (said + ": the mismatch is within the mesh's discretization error. Refine the "
                f"mesh (forward_model.fsi.mesh.preset: {fine}) before reading physics into "
                "it; candidates calibrated on this mesh may only mimic its error.")
    return said + ": the mesh's discretization error does not account for the mismatch."


def _region_words(loc: Mapping[str, Any]) -> str:
    """A located region of a 3D surface
    (:func:`~bayescalib.diagnosis.residuals.predictive_check`), in plain words."""
    x, y, z = loc["x_mm"], loc["y_mm"], loc["z_mm"]
    core = loc.get("core_where")
    n = int(loc["n_nodes"])
    return (f"Mismatch on snapshot {loc['snapshot']}: a region of {n} observed "
            f"node{'s' if n != 1 else ''} {loc['where']} of the colony (x {x[0]:.3f}-"
            f"{x[1]:.3f} mm, y {y[0]:.3f}-{y[1]:.3f} mm, z {z[0]:.3f}-{z[1]:.3f} mm), "
            f"{loc['direction']}, by up to "
            f"{1e3 * abs(loc['peak_residual_mm']):.2f} um"
            + (f"; at least half of the largest mismatch {core}." if core else "."))


def _set_aside_words(e: Mapping[str, Any], d: Mapping[str, Any]) -> str:
    """One candidate set aside (:func:`set_aside_candidates`), in plain words: why, its
    estimate, the range or threshold it violates and what the user could do."""
    name, u = e["candidate"], _unit(e["unit"])
    lo, hi = e["range"]
    what = f"{name} ({e['summary']})" if e.get("summary") else name
    seen = (f"The linearized attribution ranks it {_ordinal(int(e['rank']))} "
            f"({_p_words(float(e['p_value']))}; alone it would explain "
            f"{100 * float(e['explained_fraction']):.0f} % of the mismatch beyond noise)")
    advice = e["advice"][0].upper() + e["advice"][1:]
    if e["reason"] == "implausible magnitude":
        held = e.get("calibrated_within_range_in")
        after = (f"so it was calibrated only beside other candidates, within that range "
                 f"({', '.join(held)}; not chosen)" if held else
                 "so no extended model with it was calibrated")
        return (f"Set aside: {what}. {seen}, but its estimated magnitude, phi_{name} = "
                f"{float(e['estimate']):.3g}{u}, lies outside its plausible range "
                f"[{lo:.3g}, {hi:.3g}]{u} by more than half the range's width, {after}. "
                f"{advice}.")
    if e["reason"] == "not identifiable":
        base = ", ".join(d.get("posterior_mean") or {}) or "E, nu, ..."
        return (f"Set aside: {what}. Only {100 * float(e['identifiable_fraction']):.2g} % "
                f"of its signature is beyond what the base parameters ({base}) can mimic "
                f"(more than {100 * MIN_IDENTIFIABLE:.0f} % needed; its estimate phi_{name} "
                f"= {float(e['estimate']):.3g}{u}, {_p_words(float(e['p_value']))}): these "
                "data cannot tell it apart from them, so it can neither be blamed nor "
                f"ruled out, and no extended model with it was calibrated. {advice}.")
    return (f"Not calibrated: {what}. {seen}, with phi_{name} = "
            f"{float(e['estimate']):.3g}{u} in its range [{lo:.3g}, {hi:.3g}]{u}, but it "
            f"ranks below the candidates calibrated. {advice}.")


def _joint_words(joint: Mapping[str, Any], d: Mapping[str, Any]) -> str:
    """Why the joint model of single extensions was calibrated (:func:`joint_of_singles`)."""
    singles = joint["singles"]
    base_rms = 1e3 * float(d["check"]["residual_rms_mm"])
    head = (f"{_names([s['candidate'] for s in singles])} each fit significantly better "
            "than the base model (log Bayes factors "
            + ", ".join(f"{s['log_bayes_factor']:.2f}" for s in singles)
            + f" > ln 3; residual RMS {base_rms:.2f} -> "
            + ", ".join(f"{1e3 * s['residual_rms_mm']:.2f}" for s in singles) + " um)")
    if joint["why"] == "one explains alone":
        why = (f"; {_names([s['candidate'] for s in singles if s['explains']])} explains the "
               "mismatch alone, but the other may be a second effect beside it")
    else:
        why = (", but none explains the mismatch alone" if len(singles) > 2 else
               ", but neither explains the mismatch alone")
        why += ": each may carry a part of it"
    best = ("" if len(joint["members"]) == len(singles) else
            f" (the {len(joint['members'])} with the largest Bayes factors, "
            "diagnose.max_effects)")
    return (head + why + f". So their joint model, base + {joint['candidate']}{best}, was "
            "calibrated as well, and chosen or not by evidence and fit like the others.")


def plain_words(d: Mapping[str, Any]) -> list[str]:
    """The diagnosis in a few sentences for a mechanician."""
    chk = d["check"]
    pmin = min(chk["p_values"].values())
    lines = []
    base = d.get("base_calibration") or {}
    if base.get("converged") is False:
        lines.append(
            f"Caution: the study's calibration did NOT converge ({base['reason']}). The "
            "diagnosis judges the posterior it reported; a mismatch found below may be the "
            "surrogate's, not missing physics. Raise design.active.max_solves and rerun.")
    elif base.get("converged") is None and base.get("strategy") == "fixed":
        lines.append(
            "The study used a fixed design, so nothing checked that its posterior has "
            "converged; a mismatch found below may be the surrogate's (design.strategy: "
            "active checks it).")
    if chk["adequate"]:
        lines.append(
            f"The calibrated model reproduces the observed interface within its predictive "
            f"bands (smallest posterior predictive p-value {pmin:.3g}; residual RMS "
            f"{1e3 * chk['residual_rms_mm']:.2f} um against a noise level of "
            f"{1e3 * chk['sigma_mm']:.2f} um). No significant mismatch: nothing to add.")
        return lines
    lines.append(
        f"The calibrated model misses the data (smallest posterior predictive p-value "
        f"{pmin:.3g}; residual RMS {1e3 * chk['residual_rms_mm']:.2f} um against a noise "
        f"level of {1e3 * chk['sigma_mm']:.2f} um, {chk.get('sigma_source', 'given')}; "
        f"{_noise_words(chk)}).")
    for loc in chk["located"]:
        if "arc_length_mm" not in loc:  # a region of a 3D surface
            lines.append(_region_words(loc))
            continue
        a, b = loc["arc_length_mm"]
        core = ", ".join(f"{c0:.3f}-{c1:.3f} mm" for c0, c1 in loc.get("core_arc_length_mm", []))
        lines.append(
            f"Mismatch on snapshot {loc['snapshot']}: arc length {a:.3f}-{b:.3f} mm "
            f"(x {loc['x_mm'][0]:.3f}-{loc['x_mm'][1]:.3f} mm, y {loc['y_mm'][0]:.3f}-"
            f"{loc['y_mm'][1]:.3f} mm), {loc['direction']}, by up to "
            f"{1e3 * abs(loc['peak_residual_mm']):.2f} um"
            + (f"; at least half of the largest mismatch at arc length {core}." if core
               else "."))
    if not chk["located"]:
        lines.append("The mismatch is spread over the interface (no interval leaves the "
                     "simultaneous band of the smoothed residual).")
    zero = d.get("zero_load_snapshot")
    if zero is not None and any(loc["snapshot"] == zero for loc in chk["located"]):
        lines.append(
            f"Part of the mismatch is present at zero load (snapshot {zero}): flow-driven "
            "mechanics cannot cause it. Look at the rest shape (growth, a wrong reference "
            "geometry), the registration of the images or their segmentation.")
    disc = d.get("discretization")
    if disc is not None:
        lines.append(_discretization_words(disc, chk))
    reg = d.get("registration")
    if d.get("dim") == 3:
        lines.append("A rigid misplacement of the observed surfaces is not tested in 3D (the "
                     "registration test is that of 2D curves): the study's checks of the "
                     "volumes' origin and footprint, when it was read, are the guard.")
    if reg is not None and reg.get("significant"):
        ca = reg.get("check_after")
        refit = ", ".join(f"{k} = {v:.4g}" for k, v in
                          (reg.get("refit_parameters") or {}).items())
        after = ("" if ca is None else
                 f"; with the observations registered back and the base parameters re-fitted "
                 f"({refit}), residual RMS {1e3 * chk['residual_rms_mm']:.2f} -> "
                 f"{1e3 * ca['residual_rms_mm']:.2f} um")
        if reg.get("explains") and d["verdict"] != MISREGISTERED:
            single = len((d.get("observed_nodes") or {}).get("n_used") or [0, 0]) == 1
            lines.append(
                f"The observed interfaces look misplaced as a whole ({_registration_words(reg)}"
                f"; {_p_words(reg['p_value'])}{after}): a registration error of the images, "
                "or physics that moves the interface nearly as a whole; the data cannot "
                "tell them apart"
                + (" from one snapshot (a snapshot at zero load or at a second loading "
                   "would: a misplacement is the same at every load)" if single else "")
                + ". Check the image origin, pixel size and alignment.")
        elif reg.get("explains"):
            lines.append(
                f"The observed interfaces look misplaced as a whole ({_registration_words(reg)}"
                f"; {_p_words(reg['p_value'])}{after}): a registration error of the images, "
                "not physics. Check the image origin, pixel size and alignment, or register "
                "the observations, then recalibrate.")
        elif ca is None or not reg.get("first_order"):
            lines.append(
                f"A rigid misplacement of the observed interfaces ({_registration_words(reg)}) "
                f"is significant ({_p_words(reg['p_value'])}) but explains only "
                f"{100 * reg['explained_fraction']:.0f} % of the mismatch{after}.")
        else:
            lines.append(
                f"A rigid misplacement of the observed interfaces ({_registration_words(reg)}) "
                f"is significant ({_p_words(reg['p_value'])}) and accounts for the mismatch "
                f"to first order, but the real solves do not confirm it{after}, not within "
                f"{EXPLAINED_RMS:g} x the noise: not a misregistration.")
    rf = d.get("refit")
    if rf is not None and d["verdict"] == ABSORBED:
        moved = ", ".join(f"{k} = {v:.4g}" for k, v in rf["parameters"].items())
        lines.append(
            f"Re-fitting the base parameters locally (one Gauss-Newton step from the "
            f"posterior mean, to {moved}) leaves a residual consistent with the noise "
            f"(chi2 = {rf['chi2']:.1f} on {rf['dof']} degrees of freedom, p = "
            f"{rf['p_value']:.3g}): the calibration missed the best fit, no physics is "
            "missing. The surrogate is the likely cause; give the design more solves "
            "(design.active.max_solves) and rerun.")
    else:
        lines.append("Linearized attribution: " + d["attribution_verdict"] + ".")
    for name, why in (d.get("failed_signatures") or {}).items():
        lines.append(
            f"Not testable: {name}. Its signature solves failed at every step and place "
            f"tried (diagnosis.json: signature_attempts; {why}); "
            f"it can neither be blamed nor ruled out. To test it, {NOT_TESTABLE_ADVICE}.")
    lines += [_set_aside_words(e, d) for e in d.get("set_aside") or []
              if e["reason"] != "not testable"]
    joint = d.get("joint_of_singles")
    for e in d["extended"]:
        if joint is not None and e["candidate"] == joint["candidate"]:
            lines.append(_joint_words(joint, d))
        ca = e["check_after"]
        if ca is None:
            lines.append(
                f"With {e['candidate']} ({e['summary']}): log Bayes factor "
                f"{e['log_bayes_factor']:.2f}, {_phi_words(e)}, but the forward model does "
                f"not solve at its posterior draws ({e['check_after_failed']}), so the "
                "extension cannot be confirmed and is not chosen.")
            continue
        if not e.get("converged", True):
            lines.append(f"Caution: the calibration of base + {e['candidate']} did not "
                         f"converge ({e['reason']}); its Bayes factor and phi are "
                         "provisional (raise diagnose.max_solves).")
        if e.get("reported_round") is not None:
            rms = {int(k): v for k, v in (e.get("rechecked_rounds") or {}).items()}
            r = int(e["reported_round"])
            lines.append(
                f"Its last round's posterior (round {r + 1}) fits worse at real solves "
                f"than that of round {r} ({1e3 * rms.get(r + 1, float('nan')):.2f} against "
                f"{1e3 * rms.get(r, float('nan')):.2f} um): it moved where no solve had "
                f"checked the surrogate yet, so round {r}'s posterior is reported.")
        if not e.get("surrogate_consistent", True):
            lines.append(f"Caution: the Bayes factor of {e['candidate']} favours it, but the "
                         "forward solves at its posterior do not fit better; the surrogate "
                         "of the extended model is not reliable there (more design points).")
        lines.append(
            f"With {e['candidate']} ({e['summary']}): log Bayes factor "
            f"{e['log_bayes_factor']:.2f}, {_phi_words(e)}, residual RMS "
            f"{1e3 * chk['residual_rms_mm']:.2f} -> {1e3 * ca['residual_rms_mm']:.2f} um "
            f"({_rms_after_words(e)}), "
            f"band coverage {100 * chk['pointwise_band_coverage']:.0f} % -> "
            f"{100 * ca['pointwise_band_coverage']:.0f} %.")
        if e.get("improves") and not e.get("explains"):
            lines.append(
                f"It fits better but does not explain the mismatch: the residual stays above "
                f"{EXPLAINED_RMS:g} x the noise level "
                f"({1e3 * d.get('noise_reference_mm', ca['sigma_mm']):.2f} um) and "
                "its check fails.")
    if d["chosen_model"] != "base":
        lines.append(f"Chosen model: base + {d['chosen_model']}.")
    elif d["extended"]:
        lines.append("No extension is chosen: none explains the mismatch with the support "
                     "of the evidence; the base model stays.")
    lines.append(f"Verdict: {d['verdict']}.")
    return lines
