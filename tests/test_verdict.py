"""The verdict a run ends with (bayescalib.stages.verdict): at most three short
sentences, most important first, composed from the structured fields of summary.json
(never from the long design.reason, which stays there as the detail)."""

from __future__ import annotations

import copy
import re

import pytest

from bayescalib.stages.verdict import verdict, verdict_sentences

FIT_OK = {"misfit_nats": 0.06, "n_measurements": 1, "expected_nats": 0.5,
          "expected_sd_nats": 0.71, "p_value": 0.73, "consistent": True,
          "words": "the best solve fits the data as the likelihood's noise model expects"}
FIT_BAD = {"misfit_nats": 500.0, "n_measurements": 1, "expected_nats": 0.5,
           "expected_sd_nats": 0.71, "p_value": 1e-200, "consistent": False,
           "words": "the best solve misfits the data by 500 nats ..."}


def _round(r, n, *, settled, shift=0.05, confirmed=None, failed=0):
    return {"round": r, "n_solves": n, "n_failed": failed, "settled": settled,
            "shift_sd": None if r == 0 else shift, "sd_change": 0.01,
            "posterior_check_confirmed": confirmed, "log_weight_sd": None,
            "ess_fraction": None}


def _check(round_, confirmed, n_draws=16):
    return {"round": round_, "n_draws": n_draws, "n_failed": 0, "confirmed": confirmed,
            "log_weight_sd": 0.095 if confirmed else 3.2, "words": "16 real solves ..."}


# a long reason as acquire_round writes it: the verdict must not repeat it
LONG = ("NOT converged: the budget design.active.max_solves = 40 is spent after round 5. "
        "the posterior of round 4 was NOT confirmed by real solves of its draws (16 real "
        "solves of posterior draws: log-weight sd 3.2 nats ...); the posterior check's 16 "
        "draws do not fit in the 0 solve(s) left of the budget. " + "x" * 600)

CONVERGED = {
    "study": "smoke", "n_train": 39, "fit": FIT_OK, "posterior_check": _check(3, True),
    "design": {"strategy": "active", "n_solves": 39, "n_failed": 0, "converged": True,
               "max_solves": 40, "check_draws": 16,
               "reason": "converged after round 4 with 39 solves: ...",
               "rounds": [_round(0, 8, settled=False), _round(1, 13, settled=False, shift=1.2),
                          _round(2, 18, settled=True), _round(3, 23, settled=True),
                          _round(4, 39, settled=True, confirmed=True)]},
}


def _misfit(s):
    s = copy.deepcopy(s)
    s["fit"] = FIT_BAD
    return s


def _budget_spent_moving():
    s = copy.deepcopy(CONVERGED)
    d = s["design"]
    d.update(converged=False, n_solves=40, reason=LONG)
    d["rounds"] = d["rounds"][:4] + [_round(4, 28, settled=False, shift=0.9),
                                     _round(5, 40, settled=False, shift=0.6)]
    s["posterior_check"] = None
    return s


def _check_failed_then_no_room():
    """The issue's run-on: the last round's check NOT confirmed and no room for another."""
    s = copy.deepcopy(CONVERGED)
    d = s["design"]
    d.update(converged=False, n_solves=40, reason=LONG)
    d["rounds"] = d["rounds"][:4] + [_round(4, 24, settled=True),
                                     _round(5, 40, settled=False, shift=0.4, confirmed=False)]
    s["posterior_check"] = _check(4, False)
    return s


def _check_does_not_fit():
    """Settled, but the check round's 16 draws never fit in the budget left."""
    s = copy.deepcopy(CONVERGED)
    d = s["design"]
    d.update(converged=False, n_solves=30, max_solves=30, reason=LONG)
    d["rounds"] = d["rounds"][:4] + [_round(4, 30, settled=True)]
    s["posterior_check"] = None
    return s


def _sentences(text):
    return [t for t in re.split(r"(?<=[.])\s+(?=[A-Z])", text) if t]


def _short(s):
    sents = verdict_sentences(s)
    assert 1 <= len(sents) <= 3, sents
    assert all(len(t) <= 220 for t in sents), [len(t) for t in sents]
    assert verdict(s) == " ".join(sents)
    assert "x" * 20 not in verdict(s)  # never the long reason
    return sents


def test_converged_and_the_fit_within_the_noise_is_one_sentence():
    sents = _short(CONVERGED)
    assert sents == [("Converged after 39 of 40 solves: 16 real solves of the posterior's "
                      "draws confirm it.")]


def test_a_misfit_1000_times_the_noise_leads_before_converged():
    sents = _short(_misfit(CONVERGED))
    assert len(sents) == 3
    assert sents[0].startswith("The best fit is 1000 times worse than the noise model allows")
    assert "500 nats" in sents[0] and "0.5 +- 0.71" in sents[0]
    assert sents[1].startswith("Converged after 39 of 40 solves")
    assert "sigma_n" in sents[2] and "diagnosis" in sents[2]


def test_not_converged_with_the_budget_spent_says_the_posterior_still_moved():
    sents = _short(_budget_spent_moving())
    assert sents[0] == ("NOT converged: the budget of 40 solves is spent and the posterior "
                        "still moved by 0.6 sd in the last round.")
    assert sents[1].startswith("Raise design.active.max_solves")


def test_a_failed_check_with_no_room_left_gives_one_reason_not_two():
    text = verdict(_check_failed_then_no_room())
    _short(_check_failed_then_no_room())
    assert text.startswith("NOT converged: the budget of 40 solves is spent and real solves "
                           "of its draws did not confirm the posterior of round 4.")
    assert "do not fit" not in text and "did not fit" not in text  # the contradiction


def test_a_check_that_does_not_fit_in_the_budget_says_so():
    sents = _short(_check_does_not_fit())
    assert sents[0] == ("NOT converged: the budget of 30 solves is spent and the posterior "
                        "settled too late for its check (16 solves) to fit in the budget.")


def test_not_converged_with_a_misfit_puts_the_misfit_first_and_stays_at_three():
    sents = _short(_misfit(_budget_spent_moving()))
    assert len(sents) == 3
    assert sents[0].startswith("The best fit is")
    assert sents[1].startswith("NOT converged")
    assert "max_solves" in sents[2] and "if the misfit stays" in sents[2]


def test_every_solve_of_the_last_batch_failed():
    s = _budget_spent_moving()
    s["design"]["rounds"][-1]["n_failed"] = 12  # 28 -> 40: the 12 new ones all failed
    assert "all 12 solves of the last batch failed" in verdict(s)


@pytest.mark.parametrize("confirmed, said", [(True, "confirm it."),
                                             (False, "do NOT confirm it.")])
def test_a_fixed_design_says_convergence_was_not_checked(confirmed, said):
    s = {"study": "x", "n_train": 64, "fit": FIT_OK, "posterior_check": _check(None, confirmed),
         "design": {"strategy": "fixed", "n_solves": 64, "converged": None,
                    "reason": "fixed design ...", "rounds": []}}
    sents = _short(s)
    assert sents[0].startswith("Convergence not checked (fixed design of 64 solves)")
    assert sents[0].endswith(said)
    assert (len(sents) == 2) is (not confirmed)


def test_a_summary_without_the_budget_fields_still_reads():
    s = _budget_spent_moving()
    del s["design"]["max_solves"], s["design"]["check_draws"]
    assert _short(s)[0] == ("NOT converged after 40 solves: the posterior still moved by "
                            "0.6 sd in the last round.")


def test_an_earlier_failed_check_and_no_room_for_another():
    s = _check_does_not_fit()
    s["posterior_check"] = _check(2, False)
    assert _short(s)[0] == ("NOT converged: the budget of 30 solves is spent and the last "
                            "check (round 2) did not confirm the posterior and another (16 "
                            "solves) did not fit in the budget.")


def test_a_confirmed_check_whose_draws_moved_the_posterior():
    s = _budget_spent_moving()
    s["design"]["rounds"][-1]["posterior_check_confirmed"] = True
    s["posterior_check"] = _check(4, True)
    assert _short(s)[0] == ("NOT converged: the budget of 40 solves is spent and real solves "
                            "of its draws confirmed the posterior, but it moved by 0.6 sd "
                            "when they were added.")


def test_a_region_the_posterior_does_not_hold_is_the_reason_it_is_not_converged():
    """A run stopped with a basin of its solves outside the posterior (the exploration
    audit) says where, and how much mass could lie there, before any other reason."""
    rounds = [{"round": 0, "n_solves": 32, "n_failed": 0, "settled": False},
              {"round": 1, "n_solves": 64, "n_failed": 0, "settled": True, "shift_sd": 0.01,
               "posterior_check_confirmed": True, "explored": False,
               "unexplored_mass": 0.73, "unexplored_peak": {"E": 512.0, "nu": 0.31}}]
    s = {"design": {"strategy": "active", "n_solves": 64, "converged": False,
                    "max_solves": 64, "check_draws": 32, "rounds": rounds},
         "fit": {"consistent": True}}
    text = verdict(s)
    assert "E = 512, nu = 0.31" in text and "73 %" in text, text
    assert text.index("region") < text.index("Raise design.active.max_solves"), text


def _cut(s, *ends):
    s = copy.deepcopy(s)
    s["parameters"] = [{"name": "E", "unit": "Pa"}, {"name": "nu", "unit": "-"}]
    s["against_bounds"] = [
        {"name": n, "index": k, "side": side, "bound": b, "density_ratio": 1.0,
         "edge_mass": 0.4, "delta": 0.5, "sd_fraction": 0.002}
        for n, k, side, b in ends]
    return s


@pytest.mark.parametrize("base", [CONVERGED, _misfit(CONVERGED), _budget_spent_moving()],
                         ids=["converged", "misfit", "not converged"])
def test_a_posterior_cut_by_its_priors_ends_says_so_and_what_to_do(base):
    """The default half-ellipse fitted to the OCT example: E piles at 800 Pa, nu at -0.8
    (docs/scan_geometry.md); converged or not, the last sentence names the ends and the
    keys to widen, in place of advice that cannot help (more solves, sigma_n)."""
    sents = _short(_cut(base, ("E", 0, "upper", 800.0), ("nu", 1, "lower", -0.8)))
    assert sents[-1] == ("The prior's ends cut the posterior (E at 800 Pa, nu at -0.8): the "
                         "data favour values beyond; widen parameters[0] and parameters[1] "
                         "(prior, bounds) if they are possible, else check the units of "
                         "data, loads and priors.")
    assert not any("Raise design.active.max_solves" in t or "sigma_n" in t for t in sents)
    assert _short(base)[-1] != sents[-1]  # without a cut end: no such sentence
