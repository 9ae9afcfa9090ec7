"""Two effects present at once, each taking part of the mismatch: when the single
extensions each fit significantly better than the base model and none explains the
mismatch alone, the joint model of the best of them is calibrated too and chosen by
evidence and fit (:func:`bayescalib.diagnosis.stage.model_extensions`).

The calibration is an analytic stand-in: the data are a residual ``a g1 + b g2`` plus
Gaussian noise along 120 nodes, and "calibrating" base + a group of candidates is the
linear least-squares fit of their signatures, with the Laplace log evidence of that
linear Gaussian model under a uniform prior on each phi (exact up to the prior's
truncation). Its residual RMS and chi-square check stand for the real solves'.
Found (issue 39): a permeable biofilm and a stiff base layer hidden together; both
single extensions fitted better (RMS 1.68 -> 1.38 um and better for the layer, noise
1.2 um), the joint model was never calibrated.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2

from bayescalib.diagnosis.extended import CandidateSpec
from bayescalib.diagnosis.stage import (
    LN_BF_MIN,
    choose_extension,
    decide_verdict,
    joint_of_singles,
    model_extensions,
    plain_words,
)

N = 120
S = np.linspace(0.0, 1.0, N)
SIGMA = 1.2e-3  # mm, given
SIGS = {"permeability": np.exp(-0.5 * ((S - 0.35) / 0.12) ** 2),  # mm per unit phi
        "layer": np.exp(-0.5 * ((S - 0.6) / 0.12) ** 2),
        "growth": np.cos(3 * np.pi * S)}
PRIOR = (0.0, 0.02)
CANDS = {n: CandidateSpec(n, f"physics.{n}.phi", 1e-3, PRIOR, summary=f"{n} effect")
         for n in SIGS}


def _data(effects: dict[str, float], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return sum(phi * SIGS[n] for n, phi in effects.items()) + rng.normal(0.0, SIGMA, N)


def _log_evidence(r: np.ndarray, names: list[str]) -> tuple[float, np.ndarray, np.ndarray]:
    """Laplace log evidence of ``r = G phi + noise`` (uniform prior on each phi), the
    least-squares phi and its posterior sd."""
    k = len(names)
    base = -0.5 * float(r @ r) / SIGMA**2 - N * math.log(SIGMA * math.sqrt(2 * math.pi))
    if not k:
        return base, np.zeros(0), np.zeros(0)
    G = np.column_stack([SIGS[n] for n in names])
    phi, *_ = np.linalg.lstsq(G, r, rcond=None)
    e = r - G @ phi
    H = G.T @ G / SIGMA**2
    occam = 0.5 * k * math.log(2 * math.pi) - 0.5 * math.log(np.linalg.det(H)) \
        - k * math.log(PRIOR[1] - PRIOR[0])
    logz = -0.5 * float(e @ e) / SIGMA**2 - N * math.log(SIGMA * math.sqrt(2 * math.pi)) \
        + occam
    return logz, phi, np.sqrt(np.diag(np.linalg.inv(H)))


def _stand_in(r: np.ndarray):
    """The base check and a ``calibrate(group)`` whose records are those of the real one
    (the fields the judgement, the choice and the plain words read)."""
    base_logz, _, _ = _log_evidence(r, [])
    base = SimpleNamespace(rms=float(np.sqrt(np.mean(r**2))), sigma=SIGMA,
                           sigma_source="given")
    calls: list[list[str]] = []

    def calibrate(group):
        names = [c.name for c in group]
        calls.append(names)
        logz, phi, sd = _log_evidence(r, names)
        e = r - np.column_stack([SIGS[n] for n in names]) @ phi
        return {"candidate": " + ".join(names), "members": names,
                "summary": "; ".join(c.summary for c in group), "unit": "-",
                "log_bayes_factor": logz - base_logz, "converged": True,
                "phi": {n: {"mean": float(m), "std": float(s), "unit": "-",
                            "prior": list(PRIOR)} for n, m, s in zip(names, phi, sd)},
                "check_after": {"residual_rms_mm": float(np.sqrt(np.mean(e**2))),
                                "sigma_mm": SIGMA, "pointwise_band_coverage": 0.9,
                                "adequate": bool(chi2.sf(e @ e / SIGMA**2, N - len(names))
                                                 > 0.05)},
                "check_after_draws": {"draws": "check", "n_draws": 16, "n_failed": 0},
                "_check": None}

    return base, calibrate, calls


def _singles(*names):
    return [([CANDS[n]], "ranking") for n in names]


def _diagnosis(base, extended, joint, verdict):
    d = {"verdict": verdict, "attribution_verdict": "the mismatch is explained by layer",
         "check": {"adequate": False, "p_values": {"chi2": 1e-9},
                   "residual_rms_mm": base.rms, "sigma_mm": SIGMA, "located": [],
                   "pointwise_band_coverage": 0.5},
         "extended": extended, "joint_of_singles": joint, "noise_reference_mm": SIGMA,
         "chosen_model": (choose_extension(extended) or {"candidate": "base"})["candidate"]}
    return " ".join(plain_words(d))


def test_two_effects_that_each_explain_part_are_modelled_jointly_and_chosen():
    r = _data({"permeability": 5e-3, "layer": 5e-3})
    base, calibrate, calls = _stand_in(r)
    extended, noise_ref, joint = model_extensions(
        _singles("layer", "permeability"), calibrate, base, registration_after=None,
        max_effects=2, joint_when="unexplained")
    singles = {e["candidate"]: e for e in extended[:2]}
    # the premise: each single fits significantly better and neither explains alone
    for e in singles.values():
        assert e["log_bayes_factor"] > LN_BF_MIN and e["improves"] and not e["explains"]
        assert e["check_after"]["residual_rms_mm"] > 1.5 * SIGMA
    # so the joint model of both is calibrated, best Bayes factor first
    by_bf = sorted(singles, key=lambda n: -singles[n]["log_bayes_factor"])
    assert calls[-1] == by_bf and len(calls) == 3
    assert joint["members"] == by_bf and joint["why"] == "none explains alone"
    assert [s["candidate"] for s in joint["singles"]] == by_bf
    both = extended[-1]
    assert both["origin"] == "joint of singles" and both["members"] == by_bf
    # and, fitting to the noise with the larger evidence, it is the chosen model
    assert both["explains"] and both["check_after"]["residual_rms_mm"] < 1.5 * SIGMA
    assert choose_extension(extended) is both
    assert noise_ref == SIGMA
    for n, truth in (("permeability", 5e-3), ("layer", 5e-3)):
        assert abs(both["phi"][n]["mean"] - truth) <= 3 * both["phi"][n]["std"]
    verdict = decide_verdict(False, ["layer"], {"p_value": 0.0}, 0.05,
                             chosen=both["candidate"], modelled=True)
    assert verdict == f"mismatch explained by {both['candidate']}"
    # the plain words say why the joint model was tried, before its result
    text = _diagnosis(base, extended, joint, verdict)
    why = (f"{by_bf[0]} and {by_bf[1]} each fit significantly better than the base model "
           "(log Bayes factors")
    assert why in text
    assert "but neither explains the mismatch alone: each may carry a part of it. So " \
           f"their joint model, base + {both['candidate']}, was calibrated as well" in text
    assert text.index(why) < text.index(f"With {both['candidate']} (")
    assert f"Chosen model: base + {both['candidate']}." in text


def test_no_joint_model_when_one_effect_explains_alone_unless_asked():
    """One effect hidden (layer); permeability's signature overlaps it and so fits
    better too, but layer explains the mismatch alone: no joint model by default. With
    ``joint_of_singles: always`` it is calibrated, and the evidence keeps layer alone
    (the second phi is not needed: its Occam factor costs more than it fits)."""
    r = _data({"layer": 8e-3}, seed=1)
    base, calibrate, calls = _stand_in(r)
    extended, _, joint = model_extensions(
        _singles("layer", "permeability"), calibrate, base, registration_after=None,
        max_effects=2, joint_when="unexplained")
    layer, perm = extended
    assert layer["explains"] and perm["improves"] and perm["log_bayes_factor"] > LN_BF_MIN
    assert joint is None and len(calls) == 2
    assert choose_extension(extended) is layer

    base, calibrate, calls = _stand_in(r)
    extended, _, joint = model_extensions(
        _singles("layer", "permeability"), calibrate, base, registration_after=None,
        max_effects=2, joint_when="always")
    assert joint["why"] == "one explains alone" and calls[-1] == ["layer", "permeability"]
    assert choose_extension(extended)["candidate"] == "layer"
    text = _diagnosis(base, extended, joint, "mismatch explained by layer")
    assert "layer explains the mismatch alone, but the other may be a second effect" in text

    base, calibrate, calls = _stand_in(_data({"permeability": 5e-3, "layer": 5e-3}))
    _, _, joint = model_extensions(_singles("layer", "permeability"), calibrate, base,
                                   registration_after=None, max_effects=2, joint_when="never")
    assert joint is None and len(calls) == 2


def _judged(name, lnb, improves=True, explains=False, rms=2.0e-3):
    return {"candidate": name, "members": name.split(" + "), "log_bayes_factor": lnb,
            "improves": improves, "explains": explains,
            "check_after": {"residual_rms_mm": rms}}


@pytest.mark.parametrize("extended, max_effects, members", [
    # three fit better: the two with the largest Bayes factors (max_effects 2) ...
    ([_judged("a", 2.0), _judged("b", 9.0), _judged("c", 5.0)], 2, ["b", "c"]),
    # ... or all three with max_effects 3
    ([_judged("a", 2.0), _judged("b", 9.0), _judged("c", 5.0)], 3, ["b", "c", "a"]),
    # one model at most: no joint model
    ([_judged("a", 2.0), _judged("b", 9.0)], 1, None),
    # only one fits significantly better (ln B <= ln 3, or its real solves fit worse)
    ([_judged("a", 1.0), _judged("b", 9.0)], 2, None),
    ([_judged("a", 5.0, improves=False), _judged("b", 9.0)], 2, None),
    # the attribution selected them together: that joint model is calibrated already
    ([_judged("a", 5.0), _judged("b", 9.0), _judged("a + b", 12.0)], 2, None),
])
def test_which_joint_model_the_single_extensions_call_for(extended, max_effects, members):
    joint = joint_of_singles(extended, max_effects=max_effects, when="unexplained")
    assert (None if joint is None else joint["members"]) == members
    if joint is not None:
        assert joint["candidate"] == " + ".join(members)
        assert len(joint["singles"]) == 3  # every single that fits better, named


def test_the_joint_model_words_name_the_best_when_more_fit_better():
    from bayescalib.diagnosis.stage import _joint_words

    extended = [_judged("a", 2.0), _judged("b", 9.0), _judged("c", 5.0)]
    joint = joint_of_singles(extended, max_effects=2, when="unexplained")
    words = _joint_words(joint, {"check": {"residual_rms_mm": 3.0e-3}})
    assert words.startswith("b, c and a each fit significantly better than the base "
                            "model (log Bayes factors 9.00, 5.00, 2.00 > ln 3; residual "
                            "RMS 3.00 -> 2.00, 2.00, 2.00 um), but none explains")
    assert "base + b + c (the 2 with the largest Bayes factors, diagnose.max_effects)" in words
