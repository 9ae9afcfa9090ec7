"""The ``diagnose`` stage: check, locate, attribute, model, show (writes diagnosis.json).

0. *Start* from the study's own calibration: the posterior that ``summary.json``
   reports, with its design block (active rounds converged or not). The diagnosis does
   not re-calibrate the base model; when its calibration did not converge it says so,
   because a mismatch may then be the surrogate's and not the physics'.
1. *Check* — K posterior draws of the base calibration (systematic resampling of the
   SMC particles, seeded) are solved; :func:`~bayescalib.diagnosis.residuals.predictive_check`
   gives the residual along the observed interface with its predictive bands and the
   global p-values.
2. *Locate* — the arc-length intervals where the smoothed residual leaves its
   simultaneous band.
3. *Attribute* — solves at the posterior mean, at finite-difference steps of every
   calibrated parameter and at a step of each candidate's ``phi`` give the nuisance
   Jacobian and the candidates' signatures;
   :func:`~bayescalib.diagnosis.attribution.attribute` ranks the candidates.
4. *Model* — for the ``n_extend`` best-ranked identifiable candidates (when the check
   fails, or always with ``force_extend``), the extended model is calibrated by the
   same active-design chain as the study
   (:func:`~bayescalib.diagnosis.extended.extended_calibration`, which says whether it
   converged) and compared by its log Bayes factor.
5. *Show* — the predictive check is repeated with draws of each extended posterior:
   residual RMS, band coverage and p-values before/after, the posterior of ``phi``,
   and the change of the base parameters' error against the ground truth when known.

The chosen model is, among the extended models whose predictive check (real forward
solves at their posterior draws) fits better than the base model's, the one with the
largest log Bayes factor, if that exceeds ``ln 3``; otherwise the base model.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.diagnosis.extended import CandidateSpec, extended_calibration
from bayescalib.inference.posterior import equal_weight_draws
from bayescalib.stages import model_interfaces

__all__ = ["DEFAULT_FSI_PRIORS", "IMAGE_NOISE_LAG_PIXELS", "decide_verdict", "noise_lag", "plain_words",
           "resolve_candidates", "run_diagnosis", "thinned_observations"]

log = logging.getLogger(__name__)

ABSORBED = "mismatch absorbed by the base parameters; calibration off, no physics missing"

#: prior range of phi in the extended calibration of the built-in FSI candidates
DEFAULT_FSI_PRIORS = {
    "layer": (-2.0, 2.0), "growth": (-0.06, 0.06), "attachment": (0.0, 8.0e-4),
    "inflow_skew": (-0.8, 0.8), "stiffening": (0.0, 80.0), "gravity": (-200.0, 200.0),
}

LN_BF_MIN = math.log(3.0)


class PredictiveCheckError(ValueError):
    """Too few posterior draws could be solved for a predictive check."""


def resolve_candidates(fm: Mapping[str, Any], diagnose: Mapping[str, Any]) -> list[CandidateSpec]:
    """The candidates to test: ``diagnose.candidates`` or, for the fsi model, the built-in
    library (:data:`bayescalib.models.fsi.physics.CANDIDATES`) minus those already switched on."""
    given = diagnose.get("candidates")
    if given:
        return [CandidateSpec(name=c["name"], target=c["target"], step=float(c["step"]),
                              prior=(float(c["prior"][0]), float(c["prior"][1])),
                              unit=c.get("unit", "-"), switches=dict(c.get("switches") or {}),
                              summary=c.get("summary", ""))
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
                                 prior=DEFAULT_FSI_PRIORS[name], unit=c.unit,
                                 switches={f"physics.{name}.enabled": True}, summary=c.summary))
    return out


# ------------------------------------------------------------------------- helpers
#: lag of the noise estimate for interfaces traced from images, in pixel sizes (see
#: :func:`bayescalib.diagnosis.residuals.estimate_noise`)
IMAGE_NOISE_LAG_PIXELS = 5.0


def noise_lag(diagnose: Mapping[str, Any], observations: Mapping[str, Any]) -> float:
    """Arc length (mm) over which the noise estimate differences the residual:
    ``diagnose.noise_lag`` if set, else :data:`IMAGE_NOISE_LAG_PIXELS` times the largest
    pixel size of the image files among the observations, else 0 (adjacent nodes)."""
    from bayescalib.io.observations import IMAGE_SUFFIXES, UNITS

    if diagnose.get("noise_lag") is not None:
        return float(diagnose["noise_lag"])
    if observations.get("source") != "files":
        return 0.0
    sizes = [float(e["pixel_size"]) * UNITS[e.get("units") or "mm"]
             for e in observations.get("files") or []
             if Path(e["path"]).suffix.lower() in IMAGE_SUFFIXES and e.get("pixel_size")]
    return IMAGE_NOISE_LAG_PIXELS * max(sizes) if sizes else 0.0


def thinned_observations(obs, spacing: float):
    """The observation set with every snapshot thinned to one node per ``spacing`` mm of
    arc length (:func:`bayescalib.diagnosis.residuals.thin_nodes`; 0 = unchanged): the
    nodes the diagnosis uses when the noise is correlated along the interface (images)."""
    import dataclasses

    from bayescalib.diagnosis.residuals import thin_nodes
    from bayescalib.geometry.interface import Interface

    if spacing <= 0:
        return obs
    snaps = []
    for s in obs.snapshots:
        pts = np.asarray(s.points)
        idx = thin_nodes(pts, spacing)
        snaps.append(Interface.polyline(pts[idx], closed=s.n_cells == s.n_points and idx.size >= 3,
                                        name=s.name))
    return dataclasses.replace(obs, snapshots=snaps)


def _check_from_particles(tag: str, particles: str | Path, targets: Sequence[str],
                          switches: Mapping[str, Any], obs, fm, cfg, work: Path,
                          workers: int, warm_start, sigma):
    from bayescalib.diagnosis.residuals import predictive_check
    from bayescalib.models.forward import solve_points

    X = equal_weight_draws(particles, int(cfg["n_draws"]), int(cfg["seed"]))
    points = [{**dict(zip(targets, map(float, x), strict=True)), **switches} for x in X]
    runs = solve_points(fm, points, [work / tag / "draws" / f"{k}.h5" for k in range(len(X))],
                      workers=workers, warm_start=warm_start)
    good = [r for r in runs if r.ok]
    if len(good) < 2:
        reasons = sorted({r.reason.split(";")[0] for r in runs if not r.ok})
        raise PredictiveCheckError(
            f"diagnosis ({tag}): only {len(good)} of {len(runs)} posterior draws solved; the "
            "predictive check needs at least 2. Failures: " + "; ".join(reasons[:3]))
    n_snap = len(obs.snapshots)
    check = predictive_check(obs.snapshots, [model_interfaces(r, n_snap) for r in good],
                             labels=obs.labels, sigma=sigma, noise_floor=cfg["noise_floor"],
                             ell=cfg["smoothing"], alpha=cfg["alpha"], n_noise=cfg["n_noise"],
                             noise_lag=cfg["noise_lag_mm"],
                             rng=np.random.default_rng(int(cfg["seed"]) + 1))
    return check, len(runs) - len(good)


def _bias(summary: Mapping[str, Any], parameters: Sequence[Mapping[str, Any]]) -> dict | None:
    truth = {p["name"]: p.get("ground_truth") for p in parameters}
    if any(v is None for v in truth.values()):
        return None
    mean = summary["mean"]
    return {n: {"posterior_mean": float(mean[n]), "truth": float(t),
                "relative_error": float(abs(mean[n] - t) / abs(t)) if t else float(abs(mean[n]))}
            for n, t in truth.items() if n in mean}


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
    (:func:`bayescalib.stages.design_summary`: strategy, solves, converged, reason).

    Solves and extended calibrations are kept under ``outdir`` and reused.
    """
    from bayescalib.diagnosis.attribution import (
        attribute,
        jacobian_from_offsets,
        refit_test,
        signature_from_offsets,
    )
    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.inference.active import history_table
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.inference.posterior import read_particles_h5
    from bayescalib.io.observation_store import read_observations
    from bayescalib.models.forward import solve_points

    work = Path(outdir)
    cfg = dict(diagnose)
    obs = read_observations(obs_path)
    n_snap = len(obs.snapshots)
    space = ParameterSpace.from_config(parameters)
    targets = [p.get("target") or p["name"] for p in parameters]
    names = [p["name"] for p in parameters]
    chain = {"obs_path": obs_path, "measure_name": measure_name, "measure": measure,
             "likelihood": likelihood, "surrogate": surrogate, "smc_cfg": smc_cfg,
             "posterior_cfg": posterior_cfg, "workers": workers, "warm_start": warm_start}

    # 0: the study's calibration, as summary.json reports it ------------------------
    base_evidence = float(read_particles_h5(particles_path).log_evidence)
    base_summary = json.loads(Path(posterior_path).read_text())
    base_design = {k: design.get(k) for k in ("strategy", "n_solves", "converged", "reason")}
    cfg["noise_lag_mm"] = noise_lag(cfg, observations)
    n_observed = [len(s.points) for s in obs.snapshots]
    obs = thinned_observations(obs, cfg["noise_lag_mm"])
    sigma = cfg["noise_sigma"]
    if sigma is None and observations["source"] == "synthetic" \
            and float(observations["noise_sigma"]) > 0:
        sigma = float(observations["noise_sigma"])

    # 1-2: check and locate ------------------------------------------------------
    check, n_failed_draws = _check_from_particles("base", particles_path, targets, {}, obs, fm,
                                                  cfg, work, workers, warm_start, sigma)
    log.info("predictive check: adequate=%s p=%s", check.adequate, check.p_values)

    # 3: attribute ----------------------------------------------------------------
    cands = resolve_candidates(fm, cfg)
    theta = np.array([float(base_summary["mean"][n]) for n in names])
    lo, hi = space.bounds[:, 0], space.bounds[:, 1]
    h = float(cfg["fd_step"]) * (hi - lo)
    # step towards the box interior so the FD point stays inside the prior support
    h = np.where(theta + h > hi, -h, h)
    base_point = dict(zip(targets, map(float, theta), strict=True))
    pts = [base_point]
    for i, t in enumerate(targets):
        pts.append({**base_point, t: float(theta[i] + h[i])})
    for c in cands:
        pts.append({**base_point, c.target: c.step, **c.switches})
    runs = solve_points(fm, pts, [work / "base" / "linearization" / f"{i}.h5"
                                for i in range(len(pts))], workers=workers,
                      warm_start=warm_start)
    if not runs[0].ok:
        raise ValueError(f"diagnosis: the solve at the posterior mean failed ({runs[0].reason})")
    C0 = model_interfaces(runs[0], n_snap)
    y_parts, o_parts = [], []
    usable = [k for k, r in enumerate(runs[1:], start=1) if r.ok]
    for s in range(n_snap):
        y, o = offsets(np.asarray(obs.snapshots[s].points), C0[s],
                       [model_interfaces(runs[k], n_snap)[s] for k in usable])
        y_parts.append(y)
        o_parts.append(o)
    r = np.concatenate(y_parts)
    O = np.concatenate(o_parts, axis=1)  # (len(usable), n)
    col = {k: O[j] for j, k in enumerate(usable)}
    # offsets are measured from the posterior-mean prediction, so its own offset is 0
    zero = np.zeros(len(r))
    fd = [i for i in range(len(targets)) if 1 + i in col]
    J = jacobian_from_offsets([col[1 + i] for i in fd], zero, [h[i] for i in fd])
    signatures, failed_sig = {}, {}
    for j, c in enumerate(cands):
        k = 1 + len(targets) + j
        if k in col:
            signatures[c.name] = signature_from_offsets(col[k], zero, c.step)
        else:
            failed_sig[c.name] = runs[k].reason
    v = np.concatenate([sn.v for sn in check.snapshots])
    attr = attribute(r, J, signatures, v, alpha=cfg["alpha"], r2_min=cfg["r2_min"],
                     max_effects=cfg["max_effects"], ranges={c.name: c.prior for c in cands})
    # plain-words size of each signature's effect at the step, for the report
    for row in attr["ranking"]:
        c = next(c for c in cands if c.name == row["candidate"])
        row["summary"] = c.summary
        row["step"] = c.step
        row["unit"] = c.unit
        row["max_shift_at_step_mm"] = float(np.max(np.abs(signatures[c.name] * c.step)))

    # 4-5: model and show ------------------------------------------------------------
    extended = []
    refit = refit_test(r, J, np.full(len(r), check.sigma**2))
    refit["step"] = dict(zip([names[i] for i in fd], refit["step"], strict=True))
    refit["parameters"] = {n: float(theta[names.index(n)] + d) for n, d in refit["step"].items()}
    refit["in_bounds"] = bool(all(lo[names.index(n)] <= x <= hi[names.index(n)]
                                  for n, x in refit["parameters"].items()))
    verdict = decide_verdict(check.adequate, attr["selected"], refit, float(cfg["alpha"]))
    # when the mismatch is absorbed by the base parameters no candidate is modelled
    run_ext = (not check.adequate and verdict != ABSORBED) or bool(cfg["force_extend"])
    if run_ext and int(cfg["n_extend"]) > 0:
        ranked = [row["candidate"] for row in attr["ranking"]
                  if row["identifiable_fraction"] > 0.05 and row["phi_hat_plausible"]]
        chosen_names = list(dict.fromkeys(attr["selected"] + ranked))[: int(cfg["n_extend"])]
        n_new = int(cfg["n_train"] or active["n_initial"])
        max_new = int(cfg["max_solves"] or active["max_solves"])
        for name in chosen_names:
            c = next(c for c in cands if c.name == name)
            cal = extended_calibration(
                c, fm=fm, parameters=parameters, base_training=training_path, n_new=n_new,
                max_new=max_new, seed=int(cfg["seed"]) + 1, active=active,
                workdir=work / name, **chain)
            ext_targets = targets + [c.target]
            # an extended posterior where the forward model does not solve (the surrogate
            # interpolates over failed points) cannot be confirmed: recorded, not fatal
            try:
                after, n_fail_after = _check_from_particles(
                    name, cal["particles"], ext_targets, c.switches, obs, fm, cfg, work,
                    workers, warm_start, check.sigma if check.sigma_source == "given" else sigma)
                check_failed = None
            except PredictiveCheckError as exc:
                log.warning("%s", exc)
                after, n_fail_after, check_failed = None, int(cfg["n_draws"]), str(exc)
            post = cal["posterior"]
            phi_name = f"phi_{c.name}"
            ext = {
                "candidate": name, "summary": c.summary, "unit": c.unit,
                "log_evidence": cal["log_evidence"],
                "log_bayes_factor": cal["log_evidence"] - base_evidence,
                "phi_mean": float(post["mean"][phi_name]),
                "phi_std": float(post["std"][phi_name]),
                "phi_prior": list(c.prior), "phi_interval": post["intervals"].get(phi_name),
                "n_new_solves": cal["n_new"], "n_reused": cal["n_reused"],
                "n_failed": cal["n_failed"], "converged": cal["converged"],
                "reason": cal["reason"], "rounds": history_table(cal["rounds"]),
                "n_failed_draws_after": int(n_fail_after),
                "check_after": None if after is None else after.to_json(),
                "check_after_failed": check_failed,
                "posterior": {k: post[k] for k in ("names", "mean", "std", "map")},
                "bias_after": _bias(post, parameters),
                "particles": cal["particles"],
            }
            # the Bayes factor comes from GP surrogates: flag it when the real solves at
            # the extended posterior do not fit better than the base model
            ext["surrogate_consistent"] = bool(
                ext["log_bayes_factor"] <= LN_BF_MIN or (after is not None and after.rms < check.rms))
            ext["_check"] = after
            extended.append(ext)
    # the chosen model: among the extensions that the real solves confirm (a better fit
    # than the base model), the one with the largest log Bayes factor above ln 3
    confirmed = [e for e in extended if e["check_after"] is not None
                 and e["check_after"]["residual_rms_mm"] < check.rms
                 and e["log_bayes_factor"] > LN_BF_MIN]
    best = max(confirmed, key=lambda e: e["log_bayes_factor"], default=None)
    chosen = best["candidate"] if best is not None else "base"
    out = {
        "verdict": verdict,
        "attribution_verdict": attr["verdict"],
        "check": check.to_json(),
        "n_draws": int(cfg["n_draws"]), "n_failed_draws": int(n_failed_draws),
        "attribution": {k: attr[k] for k in ("ranking", "selected", "explained", "threshold",
                                             "steps")},
        "refit": refit,
        "failed_signatures": failed_sig,
        "posterior_mean": dict(zip(names, map(float, theta), strict=True)),
        "extended": [{k: v for k, v in e.items() if k != "_check"} for e in extended],
        "chosen_model": chosen,
        "bias_before": _bias(base_summary, parameters),
        "base_calibration": base_design,
        "hidden_truth": obs.meta.get("hidden") or None,
        "observed_nodes": {"n_observed": n_observed, "n_used": [len(s.points) for s in obs.snapshots],
                           "spacing_mm": float(cfg["noise_lag_mm"])},
        "units": "lengths mm; phi in the candidate's unit",
    }
    out["plain_words"] = plain_words(out)
    checks = {"base": check, **{e["candidate"]: e["_check"] for e in extended
                                if e["_check"] is not None}}
    return out, checks


def decide_verdict(adequate: bool, selected: Sequence[str], refit: Mapping[str, Any],
                   alpha: float) -> str:
    """The diagnosis verdict, in order of precedence.

    1. ``"no significant mismatch"``: the predictive check passes.
    2. ``"mismatch explained by <candidates>"``: the attribution selected candidates.
    3. ``"mismatch absorbed by the base parameters; ..."``: the re-fit test passes
       (``refit["p_value"] >= alpha``) at a re-fitted point inside the design box
       (``refit["in_bounds"]``; a step that leaves the box is outside the reach of
       the linearization and of the prior, so it proves nothing).
    4. ``"mismatch located; no candidate explains it"``.
    """
    if adequate:
        return "no significant mismatch"
    if selected:
        return "mismatch explained by " + " + ".join(selected)
    if refit.get("in_bounds", False) and float(refit["p_value"]) >= alpha:
        return ABSORBED
    return "mismatch located; no candidate explains it"


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
    else:
        lines.append(
            f"The calibrated model misses the data (smallest posterior predictive p-value "
            f"{pmin:.3g}; residual RMS {1e3 * chk['residual_rms_mm']:.2f} um against a noise "
            f"level of {1e3 * chk['sigma_mm']:.2f} um).")
        for loc in chk["located"]:
            a, b = loc["arc_length_mm"]
            lines.append(
                f"Mismatch on snapshot {loc['snapshot']}: arc length {a:.3f}-{b:.3f} mm "
                f"(x {loc['x_mm'][0]:.3f}-{loc['x_mm'][1]:.3f} mm, y {loc['y_mm'][0]:.3f}-"
                f"{loc['y_mm'][1]:.3f} mm), {loc['direction']}, by up to "
                f"{1e3 * abs(loc['peak_residual_mm']):.2f} um.")
        if not chk["located"]:
            lines.append("The mismatch is spread over the interface (no interval leaves the "
                         "simultaneous band of the smoothed residual).")
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
            lines.append(d["attribution_verdict"][0].upper() + d["attribution_verdict"][1:]
                         + ".")
    for e in d["extended"]:
        ca = e["check_after"]
        if ca is None:
            lines.append(
                f"With {e['candidate']} ({e['summary']}): log Bayes factor "
                f"{e['log_bayes_factor']:.2f}, phi = {e['phi_mean']:.3g} +- "
                f"{e['phi_std']:.2g} {e['unit']}, but the forward model does not solve at its "
                f"posterior draws ({e['check_after_failed']}), so the extension cannot be "
                "confirmed and is not chosen.")
            continue
        if not e.get("converged", True):
            lines.append(f"Caution: the calibration of base + {e['candidate']} did not "
                         f"converge ({e['reason']}); its Bayes factor and phi are "
                         "provisional (raise diagnose.max_solves).")
        if not e.get("surrogate_consistent", True):
            lines.append(f"Caution: the Bayes factor of {e['candidate']} favours it, but the "
                         "forward solves at its posterior do not fit better; the surrogate "
                         "of the extended model is not reliable there (more design points).")
        lines.append(
            f"With {e['candidate']} ({e['summary']}): log Bayes factor "
            f"{e['log_bayes_factor']:.2f}, phi = {e['phi_mean']:.3g} +- {e['phi_std']:.2g} "
            f"{e['unit']}, residual RMS {1e3 * chk['residual_rms_mm']:.2f} -> "
            f"{1e3 * ca['residual_rms_mm']:.2f} um, band coverage "
            f"{100 * chk['pointwise_band_coverage']:.0f} % -> "
            f"{100 * ca['pointwise_band_coverage']:.0f} %.")
    if d["chosen_model"] != "base":
        lines.append(f"Chosen model: base + {d['chosen_model']}.")
    elif d["extended"]:
        lines.append("Chosen model: the base model (no extension is supported by the evidence "
                     "and the fit).")
    return lines
