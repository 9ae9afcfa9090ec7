"""The job functions of the stages whose job is more than one call of a stage function
(the solves, summary.json). Like every stage of :data:`bayescalib.execution.jobserver.STAGES`,
each takes keyword arguments only, named as the rule's named inputs, outputs and params
(the job document, :func:`bayescalib.execution.jobserver.job_document`); the job's log is
set up before it is called. Imports are deferred: the point server imports this module,
and a solve must import nothing it has not (tests/test_jobserver.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any


def solve(*, out: str, forward_model: Mapping[str, Any], point: Mapping[str, float],
          base: str | None = None) -> None:
    """One design point's forward solve (rule solve): ``base`` is the warm-start state
    (``forward_model.warm_start: prior_centre``)."""
    from bayescalib.models.forward import solve_points
    from bayescalib.stages.files import read_stage_file

    base = base or None
    if base is not None:  # a damaged state is set aside and rebuilt, never solved from
        read_stage_file(base, "warm-start state")
    solve_points(forward_model, [point], [out], warm_start=base, reuse=False)


def predictive_solve(*, out: str, particles: str, parameters: Sequence[Mapping[str, Any]],
                     k: int, n: int, seed: int, forward_model: Mapping[str, Any]) -> None:
    """The forward solve at posterior draw ``k`` of ``n`` (rule predictive_solve)."""
    from bayescalib.models.forward import solve_points
    from bayescalib.stages.figures import posterior_draws

    point = posterior_draws(particles, parameters, int(k), int(n), int(seed))
    solve_points(forward_model, [point], [out], reuse=False)


def summary(*, out: str, study: str, parameters: Sequence[Mapping[str, Any]],
            measures: Sequence[str], figure_map: Mapping[str, Any], root: str, strategy: str,
            n_solves: int, budget: Mapping[str, Any], posterior: Sequence[str],
            training: Sequence[str], particles: Sequence[str], active: Sequence[str] = (),
            convergence: Sequence[str] = (), check: Sequence[str] = ()) -> None:
    """summary.json (rule summary): the study's results, its design, its timings, the
    GP convergence files and the posterior check (``check``: the fixed design's
    ``posterior_check.json``, the rule's input keeps its name)."""
    from bayescalib.stages.summary import (
        collect_timings,
        design_summary,
        posterior_check_summary,
        round_posterior_check_summary,
    )
    from bayescalib.stages.summary import summary as write_summary

    extra: dict[str, Any] = {
        "design": design_summary(strategy, list(active), int(n_solves), **dict(budget or {})),
        "timings_s": collect_timings(root)}
    if convergence:
        extra["gp_convergence"] = list(convergence)
    if check:  # fixed design: a list, empty when posterior_check.draws is 0
        extra["posterior_check"] = posterior_check_summary(check[0])
    elif strategy == "active":  # the last check of the rounds (None: none ran)
        extra["posterior_check"] = round_posterior_check_summary(list(active))
    write_summary(study, parameters, measures, posterior, training, particles, figure_map, out,
                  extra=extra)
