"""Calibration of the extended model "base + candidates" (step 4 of the diagnosis).

The extended parameter vector is ``(x, theta, phi_1, ..., phi_k)``: the study's
parameters plus each candidate's ``phi`` with a uniform prior on its range (one
candidate, or several modelled together: those the attribution found together, or the
single extensions that each fit better when none explains the mismatch alone,
:func:`bayescalib.diagnosis.stage.joint_of_singles`). Because every candidate is nested (``phi = 0`` is the base model exactly),
every base design point is a valid training point of the extended model at
``phi = 0``: the base training table is reused as is (unless the model has a step at
``phi = 0+``, as the permeable biofilm has: then it is trained on its own solves),
and round 0 adds ``n_new`` scrambled Sobol points over the extended box. From there the
extended model is calibrated exactly as the study was: active-design rounds with the
study's ``design.active`` settings (surrogate, SMC, trust check, stop rule, next batch),
by the same stage functions and the same solve path
(:func:`bayescalib.stages.chain.calibrate_rounds`), until the stop rule holds or the budget of
new solves is spent. The result says whether it converged.

The log Bayes factor of the extended against the base model is the difference of the
two SMC log-evidence estimates (paper Sec. 2.3; both on GP surrogates of the same
log-likelihood, so their surrogate errors partly cancel). On the scale of Kass and
Raftery, ``ln B > 1.1`` (B > 3) is positive and ``ln B > 3`` (B > 20) strong evidence.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["CandidateSpec", "extended_calibration", "extended_parameters", "joint_name"]


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
    continuous
        Whether the model is continuous in ``phi`` at ``phi = 0``; when not (the
        permeable biofilm's drained step), the base design is not reused at ``phi = 0``.
    """

    name: str
    target: str
    step: float
    prior: tuple[float, float]
    unit: str = "-"
    switches: dict[str, Any] = field(default_factory=dict)
    summary: str = ""
    continuous: bool = True


def _as_list(cands: CandidateSpec | Sequence[CandidateSpec]) -> list[CandidateSpec]:
    return [cands] if isinstance(cands, CandidateSpec) else list(cands)


def joint_name(cands: CandidateSpec | Sequence[CandidateSpec]) -> str:
    """Name of the extended model: ``"growth"``, or ``"growth + layer"`` for two."""
    return " + ".join(c.name for c in _as_list(cands))


def extended_parameters(parameters: Sequence[Mapping[str, Any]],
                        cands: CandidateSpec | Sequence[CandidateSpec]) -> list[dict[str, Any]]:
    """The study's parameter list plus ``phi_<name>`` of each candidate (uniform prior
    on its range), in the given order."""
    out = [copy.deepcopy(dict(p)) for p in parameters]
    for cand in _as_list(cands):
        lo, hi = (float(v) for v in cand.prior)
        out.append({"name": f"phi_{cand.name}", "unit": cand.unit, "target": cand.target,
                    "prior": {"type": "uniform", "lo": lo, "hi": hi}, "bounds": [lo, hi]})
    return out


def extended_calibration(
    cands: CandidateSpec | Sequence[CandidateSpec],
    *,
    fm: Mapping[str, Any],
    parameters: Sequence[Mapping[str, Any]],
    base_training: str | Path,
    n_new: int,
    max_new: int,
    seed: int,
    active: Mapping[str, Any],
    workdir: str | Path,
    **chain: Any,
) -> dict[str, Any]:
    """Calibrate base + ``cands`` (see the module docstring).

    Parameters
    ----------
    cands
        One candidate, or several modelled together (their switches all on).
    base_training
        Training table of the base calibration (its rows enter at ``phi = 0``).
    n_new
        Sobol points of round 0 over the extended box.
    max_new
        Budget of new solves (round 0 included).
    seed
        Seed of the Sobol design of round 0.
    active
        The study's validated ``design.active`` section.
    chain
        The remaining arguments of :func:`bayescalib.stages.chain.calibrate_rounds`
        (observations, measure, likelihood, surrogate, SMC and posterior settings,
        workers, warm start).

    Returns
    -------
    dict
        As :func:`~bayescalib.stages.chain.calibrate_rounds`, plus ``candidate``
        (:func:`joint_name`).
    """
    from bayescalib.inference.design import sobol_design
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.stages.chain import calibrate_rounds, training_rows

    group = _as_list(cands)
    params_ext = extended_parameters(parameters, group)
    space = ParameterSpace.from_config(params_ext)
    X0 = sobol_design(space.bounds, int(n_new), int(seed))
    # the base solves, at the candidates' zero
    reused = training_rows(base_training).with_columns(np.zeros(len(group)))
    if not all(c.continuous for c in group):
        # a model with a step at phi = 0+: the base solves would put a jump on the edge
        # of the surrogate's box, so the extended model is trained on its own solves
        reused = reused.take(slice(0, 0))
    budget = {**dict(active), "max_solves": len(reused) + int(max_new)}
    switches = {k: v for c in group for k, v in c.switches.items()}
    cal = calibrate_rounds(fm=fm, parameters=params_ext, initial=X0, switches=switches,
                           reused=reused, active=budget, workdir=workdir, **chain)
    return {"candidate": joint_name(group), **cal}
