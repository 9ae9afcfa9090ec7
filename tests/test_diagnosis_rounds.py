"""Which round represents an extended calibration that its budget stopped unconverged
(:func:`bayescalib.diagnosis.stage._better_confirmed_round`): the last round's posterior
may have moved where no solve has checked the surrogate, so the round before is
re-checked with real solves too and the one they confirm better is reported. The
re-check and the posterior summary are replaced by stand-ins here (the end-to-end path
is tests/test_diagnosis_workflow.py)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

import bayescalib.stages.marginalize as marginalize_stage
from bayescalib.diagnosis import stage
from bayescalib.inference import posterior


def _cal(tmp_path, converged=False, n_rounds=3, result_searched=False):
    """A calibration's record: its result is the last round's files, or (the last round
    refitted its choices) a full search in the calibration's folder."""
    last = tmp_path if result_searched else tmp_path / "active" / str(n_rounds - 1)
    return {"converged": converged, "rounds": [{"round": r} for r in range(n_rounds)],
            "particles": str(last / "particles.h5"), "surrogate": str(last / "surrogate.h5"),
            "posterior": {"mean": {"phi_x": 9.0}}, "log_evidence": 50.0,
            "parameters": [{"name": "phi_x"}], "workdir": str(tmp_path)}


@pytest.fixture
def rechecks(monkeypatch):
    """Stand-ins: the re-check of round r returns the RMS given in ``rms[r]``."""
    rms: dict[int, float] = {}
    calls: list[str] = []

    def check(ctx, model, particles, tag, seed):
        r = int(str(particles).split("/")[-2])
        calls.append(tag)
        return SimpleNamespace(rms=rms[r]), 0, None

    monkeypatch.setattr(stage, "_predictive_check_at_draws", check)
    monkeypatch.setattr(marginalize_stage, "marginalize",
                        lambda particles, *a, **k: {"mean": {"phi_x": 4.0}, "from": str(particles)})
    monkeypatch.setattr(posterior, "read_particles_h5",
                        lambda p: SimpleNamespace(log_evidence=42.0))
    return rms, calls


def _context(seed=0, n_draws=16):
    """A stand-in context: the settings these helpers read (the solves are stand-ins)."""
    return SimpleNamespace(settings={"seed": seed, "n_draws": n_draws}, posterior_cfg={},
                           smc_cfg={"seed": 0})


def _model():
    return stage.CheckedModel("x", [], {}, 1e-3)


def _pick(cal, last_rms, tmp_path):
    return stage._better_confirmed_round(_context(), cal, SimpleNamespace(rms=last_rms), 0,
                                         _model())


@pytest.mark.parametrize("result_searched", [False, True])
def test_the_round_before_is_reported_when_real_solves_confirm_it_better(
        tmp_path, rechecks, result_searched):
    """Whether the result is the last round's files or a full search fitted after the
    rounds (in the folder above them), the round before is found in the rounds' folder
    (the second case read a folder named after the round beside the calibrations)."""
    rms, calls = rechecks
    rms[1] = 1.67e-3  # two_effects (concealed): round 26 at 1.67 um, its last round at 5.34 um
    cal, after, _, rechecked = _pick(_cal(tmp_path, result_searched=result_searched),
                                     5.34e-3, tmp_path)
    assert rechecked == {2: 5.34e-3, 1: 1.67e-3}
    assert after.rms == 1.67e-3 and calls == ["x/round_1"]
    assert cal["reported_round"] == 1
    assert cal["particles"].endswith("active/1/particles.h5")
    assert cal["surrogate"].endswith("active/1/surrogate.h5")
    assert cal["log_evidence"] == 42.0  # the SMC evidence of round 1, not of the last
    assert cal["posterior"]["mean"] == {"phi_x": 4.0}
    assert cal["posterior"]["from"].endswith("active/1/particles.h5")


def test_the_last_round_stays_when_it_fits_as_well_or_better(tmp_path, rechecks):
    rms, _ = rechecks
    for prev in (2.0e-3, 1.0e-3):  # a tie keeps the last round
        rms[1] = prev
        given = _cal(tmp_path)
        cal, after, _, rechecked = _pick(given, 1.0e-3, tmp_path)
        assert cal is given and after.rms == 1.0e-3 and "reported_round" not in cal
        assert rechecked == {2: 1.0e-3, 1: prev}


def test_no_second_check_for_a_converged_or_single_round_calibration(tmp_path, rechecks):
    _, calls = rechecks
    for given in (_cal(tmp_path, converged=True), _cal(tmp_path, n_rounds=1)):
        cal, _, _, rechecked = _pick(given, 3.0e-3, tmp_path)
        assert cal is given and rechecked is None
    assert calls == []


# --- the reported check: fresh draws of the kept round (stage._reported_predictive_check)

@pytest.fixture
def fresh_checks(monkeypatch):
    """Stand-in re-check: records (tag, particles, seed) and returns an RMS of 2.0e-3."""
    calls: list[tuple[str, str, int]] = []

    def check(ctx, model, particles, tag, seed):
        calls.append((tag, str(particles), int(seed)))
        return SimpleNamespace(rms=2.0e-3), 1, None

    monkeypatch.setattr(stage, "_predictive_check_at_draws", check)
    return calls


def _report(cal, after, rechecked, tmp_path, seed=5):
    return stage._reported_predictive_check(_context(seed=seed), cal, after, 0, rechecked,
                                            _model())


def test_the_reported_rms_comes_from_fresh_draws_of_the_kept_round(tmp_path, fresh_checks):
    """Two rounds compared: the kept round's check was chosen as the smaller of two
    RMS, so the report solves 16 other draws of the kept posterior (seed + 1000)."""
    kept = tmp_path / "active" / "1" / "particles.h5"
    cal = {**_cal(tmp_path), "reported_round": 1, "particles": str(kept)}
    selected = SimpleNamespace(rms=1.67e-3)  # two_effects: round 26 kept over 27 (5.34 um)
    rechecked = {2: 5.34e-3, 1: 1.67e-3}
    after, n_fail, src = _report(cal, selected, rechecked, tmp_path)
    assert fresh_checks == [("x/report", str(kept), 5 + stage.REPORT_SEED_OFFSET)]
    assert after is not selected and after.rms == 2.0e-3 and n_fail == 1
    assert src == {"draws": "fresh", "seed": 1005, "n_draws": 16, "n_failed": 1,
                   "selection_rms_mm": 1.67e-3}


def test_fresh_draws_also_when_the_last_round_is_kept(tmp_path, fresh_checks):
    """A kept last round was chosen too (its RMS was not larger than the other's)."""
    cal = _cal(tmp_path)
    after, _, src = _report(cal, SimpleNamespace(rms=1.0e-3), {2: 1.0e-3, 1: 2.0e-3},
                            tmp_path)
    assert [c[1] for c in fresh_checks] == [cal["particles"]]
    assert after.rms == 2.0e-3 and src["selection_rms_mm"] == 1.0e-3


def test_no_fresh_draws_where_nothing_was_chosen_on_the_draws(tmp_path, fresh_checks):
    """Converged (no second check) or a round-before check that failed (one entry):
    the check decided nothing and is reported as it is."""
    given = SimpleNamespace(rms=3.0e-3)
    for rechecked in (None, {2: 3.0e-3}):
        after, n_fail, src = _report(_cal(tmp_path), given, rechecked, tmp_path)
        assert after is given and n_fail == 0
        assert src == {"draws": "check", "seed": 5, "n_draws": 16, "n_failed": 0}
    assert fresh_checks == []


def test_fresh_draws_that_do_not_solve_leave_the_extension_unconfirmed(tmp_path, monkeypatch):
    def check(*args, **kwargs):
        raise stage.PredictiveCheckError("only 1 of 16 posterior draws solved")

    monkeypatch.setattr(stage, "_predictive_check_at_draws", check)
    after, n_fail, src = _report(_cal(tmp_path), SimpleNamespace(rms=1.0e-3),
                                 {2: 1.0e-3, 1: 2.0e-3}, tmp_path)
    assert after is None and n_fail == 16
    assert src["draws"] == "fresh" and "only 1 of 16" in src["failed"]
