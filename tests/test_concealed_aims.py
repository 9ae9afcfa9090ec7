"""The aims of the concealed-effect benchmark (benchmarks/concealed.py, issue 15), as
``docs/diagnosis.md`` checks them row by row: each aim is met, missed or not
applicable exactly as the issue states it (RMS after within 1.5 x the noise, base
errors at least halved, IoU >= 0.5 against the unabsorbable part, verdict and chosen
model never disagreeing, untestable candidates named, nothing claimed in the null
case, a misregistration called registration)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("concealed", REPO / "benchmarks" / "concealed.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _row(**kw) -> dict:
    """A benchmark row (the fields ``aims`` reads) of a well-diagnosed growth case."""
    row = {"study": "growth", "name": "concealed_growth", "hidden": "physics.growth.phi=0.02",
           "hidden_candidates": ["growth"], "hidden_misregistration": None,
           "verdict": "mismatch explained by growth", "chosen": "growth", "top1": "growth",
           "selected": ["growth"], "sigma_um": 1.0, "rms_before_um": 6.0, "rms_after_um": 1.2,
           "err_before": {"E": 0.2, "nu": 0.5}, "err_after": {"E": 0.05, "nu": 0.1},
           "err_registered": {}, "overlap_unabsorbable": 0.6, "n_located": 2,
           "located_snapshots": ["load_0"], "zero_load_snapshot": "load_0",
           "failed_signatures": {}, "plain_words": ["Verdict: mismatch explained by growth."]}
    row.update(kw)
    return row


def _met(bench, row) -> dict:
    return {a["aim"]: a["met"] for a in bench.aims(row)}


def test_a_well_diagnosed_in_library_case_meets_every_aim(bench):
    met = _met(bench, _row())
    assert met == {"verdict and chosen model agree": True, "untestable candidates named": None,
                   "top-1": True, "modelled (chosen)": True, "RMS after <= 1.5 x noise": True,
                   "base-parameter error halved": True, "IoU (unabsorbable) >= 0.5": True}


def test_the_tolerances_are_the_issues(bench):
    # RMS 1.6 um against 1 um noise is beyond 1.5 x; E 20 % -> 11 % is not halved;
    # IoU 0.49 is below 0.5
    met = _met(bench, _row(rms_after_um=1.6, err_after={"E": 0.11, "nu": 0.1},
                           overlap_unabsorbable=0.49))
    assert met["RMS after <= 1.5 x noise"] is False
    assert met["base-parameter error halved"] is False
    assert met["IoU (unabsorbable) >= 0.5"] is False


def test_two_effects_need_both_selected_and_the_joint_model_chosen(bench):
    two = _row(hidden_candidates=["growth", "attachment"], selected=["growth"],
               chosen="growth", verdict="mismatch explained by growth")
    met = _met(bench, two)
    assert met["all selected"] is False and met["modelled (chosen)"] is False
    both = _row(hidden_candidates=["growth", "attachment"], selected=["growth", "attachment"],
                chosen="growth + attachment",
                verdict="mismatch explained by growth + attachment")
    met = _met(bench, both)
    assert met["all selected"] is True and met["modelled (chosen)"] is True


def test_a_verdict_that_contradicts_the_chosen_model_is_caught(bench):
    # the held-back out-of-library case of issue 15: "no candidate explains it" with a
    # chosen extension
    row = _row(hidden_candidates=[], hidden="geometry.width=0.615", chosen="stiffening",
               verdict="mismatch located; no candidate explains it")
    met = _met(bench, row)
    assert met["verdict and chosen model agree"] is False
    assert met["not attributed"] is False
    ok = _met(bench, _row(hidden_candidates=[], hidden="geometry.width=0.615", chosen="base",
                          verdict="mismatch located; no candidate explains it"))
    assert ok["verdict and chosen model agree"] is True and ok["not attributed"] is True


def test_an_untestable_candidate_must_be_named_in_the_words(bench):
    failed = {"layer": "loading load_0: wall-clock time limit reached"}
    assert _met(bench, _row(failed_signatures=failed))["untestable candidates named"] is False
    named = _row(failed_signatures=failed, plain_words=["Not testable: layer. ..."])
    assert _met(bench, named)["untestable candidates named"] is True


def test_the_null_case_claims_nothing(bench):
    null = _row(hidden_candidates=[], hidden="none", chosen="base", selected=[],
                verdict="no significant mismatch")
    assert _met(bench, null) == {"verdict and chosen model agree": True,
                                 "untestable candidates named": None,
                                 "nothing claimed (null)": True}
    claim = _row(hidden_candidates=[], hidden="none", chosen="base", selected=["layer"],
                 verdict="mismatch attributed to layer (not modelled)")
    assert _met(bench, claim)["nothing claimed (null)"] is False


def test_a_misregistration_is_called_registration_and_its_refit_is_checked(bench):
    row = _row(hidden_candidates=[], hidden="misregistration(shift_x=0.004)",
               hidden_misregistration={"shift_x": 0.004}, chosen="base", selected=[],
               verdict="mismatch explained by a misregistration of the observed interfaces "
                       "(not physics)",
               plain_words=["Part of the mismatch is present at zero load (snapshot load_0)"],
               err_registered={"E": 0.001, "nu": 0.06}, err_before={"E": 0.26, "nu": 0.25},
               overlap_unabsorbable=0.75)
    met = _met(bench, row)
    assert met["called registration, not physics"] is True
    assert met["no physics candidate chosen"] is True
    assert met["mismatch at zero load said"] is True
    assert met["base-parameter error halved (re-fit with the registration)"] is True
    blamed = {**row, "verdict": "mismatch explained by growth", "chosen": "growth",
              "selected": ["growth"]}
    met = _met(bench, blamed)
    assert met["called registration, not physics"] is False
    assert met["no physics candidate chosen"] is False


def test_the_localization_aim_is_judged_on_the_core_where_one_is_recorded(bench):
    # a large mismatch: the band marks nearly everything (IoU 0.3), its half-maximum
    # core the effect's region (IoU 0.7); a diagnosis from before cores: the intervals
    core = _met(bench, _row(overlap_unabsorbable=0.3, core_overlap_unabsorbable=0.7))
    assert core["IoU (unabsorbable) >= 0.5"] is True
    old = _met(bench, _row(overlap_unabsorbable=0.3, core_overlap_unabsorbable=None))
    assert old["IoU (unabsorbable) >= 0.5"] is False


def test_the_core_overlap_counts_only_the_core_nodes(bench):
    labels = ["load_0", "load_1"]
    regions = [np.zeros(10, bool), np.zeros(10, bool)]
    regions[1][4:7] = True  # the effect: nodes 4-6 of the second snapshot
    diag = {"check": {"located": [
        {"snapshot": "load_1", "nodes": [0, 9], "core_nodes": [[4, 6]]},
        {"snapshot": "load_0", "nodes": [2, 3], "core_nodes": []}]}}
    assert bench._overlap(diag, regions, labels) == pytest.approx(3 / 12)
    assert bench._overlap(diag, regions, labels, core=True) == pytest.approx(1.0)
    del diag["check"]["located"][0]["core_nodes"]
    assert bench._overlap(diag, regions, labels, core=True) is None


def test_the_truth_inside_the_chosen_posterior_is_reported_beside_the_halving(bench):
    # E 3.5 % -> 5.2 % is not halved, but 0.9 posterior sd from the truth: both said
    row = _row(err_before={"E": 0.035, "nu": 0.49}, err_after={"E": 0.052, "nu": 0.27},
               z_after={"E": 0.9, "nu": 0.9})
    met = _met(bench, row)
    assert met["base-parameter error halved"] is False
    assert met["base parameters' truth within 2 posterior sd (chosen model)"] is True
    far = _met(bench, {**row, "z_after": {"E": 2.5, "nu": 0.9}})
    assert far["base parameters' truth within 2 posterior sd (chosen model)"] is False
    # rows without posterior sds (older results) get no such row
    assert "base parameters' truth within 2 posterior sd (chosen model)" not in _met(bench, _row())


def test_a_rerun_replaces_its_stored_row_and_keeps_the_others(bench):
    """The page is made from the stored rows merged with those just tabulated: a case
    rerun replaces its row (same study, loadings, observations), the others stay, a
    failed run replaces nothing, and the order is the benchmark's."""
    old_growth = _row(rms_after_um=2.0)
    null = _row(study="null", name="concealed_null")
    images = _row(observations="images", name="concealed_growth_images")
    stored = [{**r, "loadings": "several", "observations": r.get("observations", "synthetic")}
              for r in (null, old_growth, images)]
    new_growth = {**stored[1], "rms_after_um": 1.1}
    failed_null = {"study": "null", "loadings": "several", "observations": "synthetic",
                   "verdict": "RUN FAILED"}
    merged = bench.merge_rows(stored, [new_growth, failed_null])
    assert [(r["study"], r["observations"]) for r in merged] == [
        ("growth", "synthetic"), ("growth", "images"), ("null", "synthetic")]
    assert merged[0]["rms_after_um"] == 1.1
    assert merged[2]["verdict"] != "RUN FAILED"
    # a case never measured before is listed even when its run failed
    first = {**failed_null, "study": "layer"}
    assert bench.merge_rows(stored, [first])[2]["verdict"] == "RUN FAILED"


def test_a_row_names_the_commit_it_was_measured_at(bench, tmp_path):
    root = tmp_path / "results" / "concealed_growth"
    (root / "diagnosis").mkdir(parents=True)
    (root / "diagnosis" / "diagnosis.json").write_text("{}")
    out = tmp_path / "out"
    unknown = bench._read_stamp(out, root)
    assert unknown["commit"] == "unknown" and unknown["date"][:2] == "20"
    bench._record_stamp(out, root, started=0.0)
    stamp = bench._read_stamp(out, root)
    assert stamp["commit"] not in ("", "unknown") and stamp == bench._measured_at()
    # a reused run (its diagnosis older than the run) keeps its record
    (out / "measured" / "concealed_growth.json").write_text('{"commit": "abc", "date": "d"}')
    bench._record_stamp(out, root, started=root.stat().st_mtime + 1e6)
    assert bench._read_stamp(out, root) == {"commit": "abc", "date": "d"}


def test_a_candidate_set_aside_must_be_named_in_the_plain_words(bench):
    # issue 39: nothing set aside unseen (growth out of its prior range)
    aside = [{"candidate": "growth", "reason": "implausible magnitude", "estimate": 0.15,
              "range": [-0.06, 0.06], "unit": "-"}]
    named = _row(chosen="base", verdict="mismatch located; no candidate explains it",
                 set_aside=aside, plain_words=["Set aside: growth (isotropic growth). ..."])
    assert _met(bench, named)["candidates set aside named"] is True
    silent = _row(chosen="base", verdict="mismatch located; no candidate explains it",
                  set_aside=aside, plain_words=["Verdict: no candidate explains it."])
    assert _met(bench, silent)["candidates set aside named"] is False
    # rows measured before the record existed: not applicable, no aim
    assert "candidates set aside named" not in _met(bench, _row())
