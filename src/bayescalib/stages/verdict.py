"""What a finished run says at a glance: the verdict, in at most three short sentences.

Most important first:

1. the misfit, when the best solve fits the data worse than the likelihood's noise
   model allows (``fit`` of summary.json, :func:`bayescalib.inference.likelihood.fit_check`):
   every other statement is then about a model that does not reproduce the data;
2. converged or NOT converged (or, for a fixed design, not checked), with the one main
   reason, read from the structured fields of summary.json (``design``: the per-round
   history, the budget; ``posterior_check``: the last check of the posterior with real
   solves), never from the long ``design.reason`` text, which stays in summary.json and
   the report as the detail;
3. what to do, when there is something to do; first of all when the posterior is cut
   by an end of a parameter's prior box (``against_bounds`` of summary.json,
   :func:`bayescalib.inference.posterior.against_bounds`): the data favour values the
   prior excludes, which a unit slip (of the data, the loads or the prior) or a prior
   too narrow causes, and every other number is then the box's as much as the data's.

:func:`verdict` is pure (a summary.json mapping in, a string out); the run's last lines
(the Snakefile's ``onsuccess``), ``bayescalib summary`` and the report's front page
print it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["verdict", "verdict_sentences"]


def _g(v: float) -> str:
    return f"{float(v):.3g}"


def _sd(v: float) -> str:
    """A shift in posterior sd, to two digits."""
    return f"{float(v):.2g}"


def _misfit_sentence(fit: Mapping[str, Any]) -> str:
    misfit = float(fit["misfit_nats"])
    expected = float(fit.get("expected_nats") or 0.0)
    sd = fit.get("expected_sd_nats")
    noise = f"{_g(expected)} +- {float(sd):.2g}" if sd is not None else _g(expected)
    ratio = misfit / expected if expected > 0 else 0.0
    if ratio >= 10:
        how = f"{ratio:.0f} times worse than"
    elif ratio >= 2:
        how = f"{ratio:.2g} times worse than"
    else:
        how = "worse than"
    return (f"The best fit is {how} the noise model allows: a misfit of {_g(misfit)} nats "
            f"where noise alone gives {noise} nats.")


def _batch_all_failed(rounds: Sequence[Mapping[str, Any]]) -> int:
    """Size of the last round's batch when every solve of it failed, else 0."""
    if len(rounds) < 2:
        return 0
    new = int(rounds[-1]["n_solves"]) - int(rounds[-2]["n_solves"])
    failed = int(rounds[-1]["n_failed"]) - int(rounds[-2]["n_failed"])
    return new if new > 0 and failed == new else 0


def _not_converged_reason(design: Mapping[str, Any],
                          posterior_check: Mapping[str, Any] | None) -> str:
    """The one main reason an active design stopped NOT converged, from its fields."""
    rounds = design.get("rounds") or []
    last = rounds[-1] if rounds else {}
    n_failed_batch = _batch_all_failed(rounds)
    if n_failed_batch:
        return (f"all {n_failed_batch} solves of the last batch failed (failed_runs in "
                f"summary.json gives the reasons)")
    unexplored = last.get("unexplored_mass")
    if last.get("explored") is False and last.get("unexplored_peak"):
        where = ", ".join(f"{k} = {float(v):.4g}" for k, v in last["unexplored_peak"].items())
        return (f"the solves rise towards a region near {where} that the posterior does not "
                f"hold, where up to {100 * float(unexplored):.0f} % of its mass could lie")
    confirmed = last.get("posterior_check_confirmed")
    checked = None if posterior_check is None else posterior_check.get("round")
    if confirmed is False:
        of = "" if checked is None else f" of round {checked}"
        return f"real solves of its draws did not confirm the posterior{of}"
    if confirmed is True and last.get("shift_sd") is not None:
        return (f"real solves of its draws confirmed the posterior, but it moved by "
                f"{_sd(last['shift_sd'])} sd when they were added")
    if last.get("settled") is False and last.get("shift_sd") is not None:
        return f"the posterior still moved by {_sd(last['shift_sd'])} sd in the last round"
    draws = design.get("check_draws")
    if draws and posterior_check is not None and posterior_check.get("confirmed") is False:
        return (f"the last check (round {posterior_check.get('round')}) did not confirm the "
                f"posterior and another ({draws} solves) did not fit in the budget")
    if draws:
        return (f"the posterior settled too late for its check ({draws} solves) to fit in "
                f"the budget")
    return "the stop rule's tests were not all met (design.reason in summary.json)"


def _bounds_sentence(summary: Mapping[str, Any]) -> str | None:
    """What to do when an end of a parameter's box cuts its posterior, or None."""
    cut = summary.get("against_bounds") or []
    if not cut:
        return None
    units = {p["name"]: p.get("unit") for p in summary.get("parameters") or []}

    def where(c: Mapping[str, Any]) -> str:
        unit = units.get(c["name"])
        unit = f" {unit}" if unit and unit not in ("-", "1") else ""
        return f"{c['name']} at {_g(c['bound'])}{unit}"

    keys = sorted({f"parameters[{int(c['index'])}]" for c in cut})
    return (f"The prior's ends cut the posterior ({', '.join(where(c) for c in cut)}): the "
            f"data favour values beyond; widen {' and '.join(keys)} (prior, bounds) if they "
            f"are possible, else check the units of data, loads and priors.")


def verdict_sentences(summary: Mapping[str, Any]) -> list[str]:
    """The verdict of a finished run as at most three sentences, most important first
    (the module docstring). ``summary`` is summary.json as a mapping."""
    fit = summary.get("fit") or {}
    design = summary.get("design") or {}
    posterior_check = summary.get("posterior_check") or None
    misfit = fit.get("consistent") is False and fit.get("misfit_nats") is not None
    bounds = _bounds_sentence(summary)
    out = [_misfit_sentence(fit)] if misfit else []
    n = design.get("n_solves", summary.get("n_train"))
    budget = design.get("max_solves")
    used = f"{n} of {budget} solves" if budget is not None else f"{n} solves"
    converged = design.get("converged")
    misfit_advice = ("check likelihood.sigma_n against the data's noise, or run the "
                     "diagnosis (diagnose.enabled: true) for missing physics")
    if converged is True:
        if (posterior_check and posterior_check.get("confirmed")
                and posterior_check.get("n_draws") is not None):
            k = int(posterior_check["n_draws"]) - int(posterior_check.get("n_failed") or 0)
            out.append(f"Converged after {used}: {k} real solves of the posterior's draws "
                       f"confirm it.")
        else:
            out.append(f"Converged after {used} on the surrogate's own checks, without real "
                       f"solves of the posterior's draws (posterior_check.draws: 0).")
        if bounds:
            out.append(bounds)
        elif misfit:
            out.append(misfit_advice[0].upper() + misfit_advice[1:] + ".")
    elif converged is False:
        spent = budget is not None and n is not None and int(n) >= int(budget)
        head = (f"NOT converged: the budget of {budget} solves is spent and" if spent else
                f"NOT converged after {used}:")
        out.append(f"{head} {_not_converged_reason(design, posterior_check)}.")
        todo = ("Raise design.active.max_solves and run the same command again (finished "
                "solves are kept)")
        out.append(todo + ("; if the misfit stays, check likelihood.sigma_n or run the "
                           "diagnosis." if misfit else "."))
        if bounds:  # before the budget's advice: more solves do not move a prior's end
            out[-1] = bounds
    else:  # a fixed design: no stop rule, perhaps a final check with real solves
        if posterior_check and posterior_check.get("n_draws") is not None:
            k = int(posterior_check["n_draws"]) - int(posterior_check.get("n_failed") or 0)
            said = "confirm" if posterior_check.get("confirmed") else "do NOT confirm"
            out.append(f"Convergence not checked (fixed design of {n} solves); {k} real "
                       f"solves of the posterior's draws {said} it.")
        else:
            out.append(f"Convergence not checked (fixed design of {n} solves, no posterior "
                       f"check).")
        if bounds:
            out.append(bounds)
        elif misfit:
            out.append(misfit_advice[0].upper() + misfit_advice[1:] + ".")
        elif not (posterior_check and posterior_check.get("confirmed")):
            out.append("Use design.strategy: active to have it checked.")
    return out[:3]


def verdict(summary: Mapping[str, Any]) -> str:
    """:func:`verdict_sentences` as one string."""
    return " ".join(verdict_sentences(summary))
