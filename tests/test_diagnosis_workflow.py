"""The diagnose stage end to end on the analytic stand-in model (known missing term):
a hidden base slip must be located, attributed to the right candidate, and modelled
with a clear Bayes factor; without a hidden effect nothing may be claimed."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from _workflow_helpers import DATA, setup_study, smk

pytestmark = pytest.mark.workflow


@pytest.fixture(scope="module")
def concealed():
    return yaml.safe_load((DATA / "analytic_concealed.yaml").read_text())


def _diagnosis(tmp, cfg):
    setup_study(tmp, cfg)
    # a base calibration, the diagnosis and up to three extended calibrations; the limit
    # only guards against a hang (on a shared machine the two-effect case ran past 10 min)
    smk(tmp, timeout=1800)
    root = tmp / "results" / cfg["study"]
    return json.loads((root / "diagnosis" / "diagnosis.json").read_text()), root


@pytest.mark.extended
def test_hidden_slip_is_located_named_modelled_and_improves_the_fit(tmp_path, concealed):
    # a budget of 192 new solves for the extension: with the study's 128 its rounds end
    # one round short of the stop rule (an unheld basin at the nu = -0.8 bound seen in the
    # last round, whose batch the budget cut), and whether they do hangs on the GP fit's
    # optimum to 1e-6 (two BLAS threads converged at round 9, one did not)
    cfg = {**concealed, "diagnose": {**concealed["diagnose"], "max_solves": 192}}
    d, root = _diagnosis(tmp_path, cfg)
    assert d["check"]["adequate"] is False
    assert d["check"]["located"], "no mismatch interval located"
    assert d["attribution"]["ranking"][0]["candidate"] == "base_slip"
    assert d["attribution"]["selected"] == ["base_slip"]
    assert d["chosen_model"] == "base_slip"
    slip = next(e for e in d["extended"] if e["candidate"] == "base_slip")
    assert slip["log_bayes_factor"] > 3.0  # strong evidence (B > 20)
    assert slip["check_after"]["residual_rms_mm"] < 0.6 * d["check"]["residual_rms_mm"]
    # the extended model is calibrated by the study's active-design chain: round 0 is
    # diagnose.n_train Sobol points plus the base design at phi = 0, then batches of
    # design.active.batch_size acquired points, design.active.check_points (1) random
    # check points and at most design.active.probes (2) probes of basins the posterior does
    # not hold, until the stop rule holds (the last batch cut to the budget's rest)
    assert slip["converged"] is True, slip["reason"]
    assert slip["n_reused"] == 32
    rounds = slip["rounds"]
    assert [h["round"] for h in rounds] == list(range(len(rounds)))
    assert rounds[-1]["n_solves"] == 32 + slip["n_new_solves"]
    sizes = np.diff([32] + [h["n_solves"] for h in rounds])
    assert sizes[0] == 32 and np.all((sizes[1:-1] >= 8 + 1) & (sizes[1:-1] <= 8 + 1 + 2))
    assert 0 < sizes[-1] <= 8 + 1 + 2
    assert d["base_calibration"]["strategy"] == "fixed"
    assert any("fixed design" in line for line in d["plain_words"])
    for fam in ("residuals", "interface_residual", "candidates"):
        assert (root / "figures" / "diagnosis" / f"{fam}.png").stat().st_size > 1000
    html = (root / "diagnosis" / "diagnosis.html").read_text()
    assert "base_slip" in html and "Verdict" in html


@pytest.mark.extended
def test_no_hidden_effect_no_claim(tmp_path, concealed):
    cfg = {**concealed, "study": "analytic_null",
           "observations": {**concealed["observations"], "hidden": {}}}
    d, _ = _diagnosis(tmp_path, cfg)
    assert d["verdict"] == "no significant mismatch"
    assert d["extended"] == [] and d["chosen_model"] == "base"


@pytest.mark.extended
def test_an_unconverged_calibration_is_judged_with_a_caution(tmp_path, concealed):
    """No hidden effect, a sharp likelihood (sigma_N = 3 um, the noise is 1 um) and an
    active design stopped by its budget after two rounds: the study's calibration is not
    converged, and the diagnosis must say so before it judges the model (the mismatch it
    may find can be the surrogate's)."""
    cfg = {**concealed, "study": "analytic_sharp",
           "observations": {**concealed["observations"], "hidden": {}},
           "likelihood": {"sigma_n2": 9.0e-6},
           "design": {"strategy": "active", "seed": 1,
                      "active": {"n_initial": 8, "batch_size": 4, "max_solves": 12}},
           "diagnose": {**concealed["diagnose"], "n_extend": 0}}
    d, root = _diagnosis(tmp_path, cfg)
    summary = json.loads((root / "summary.json").read_text())
    assert summary["converged"] is False
    assert d["base_calibration"]["converged"] is False
    assert d["base_calibration"]["n_solves"] == 12
    assert d["plain_words"][0].startswith("Caution: the study's calibration did NOT converge")


@pytest.mark.extended
def test_an_unconverged_extension_is_represented_by_its_better_confirmed_round(
        tmp_path, concealed):
    """An extended calibration stopped by its budget (8 Sobol points, 12 new solves: two
    rounds) may end on a posterior that moved where no solve has checked the surrogate.
    The diagnosis re-checks the last two rounds' posteriors with real solves and reports
    the one they confirm better (smaller residual RMS): its check, posterior and SMC log
    evidence, and says so in plain words when it is not the last."""
    cfg = {**concealed, "study": "analytic_budget",
           "diagnose": {**concealed["diagnose"], "n_train": 8, "max_solves": 12,
                        "n_extend": 1}}
    d, _ = _diagnosis(tmp_path, cfg)
    slip = next(e for e in d["extended"] if e["candidate"] == "base_slip")
    assert slip["converged"] is False
    last = slip["rounds"][-1]["round"]
    assert last >= 1
    rms = {int(k): v for k, v in slip["rechecked_rounds"].items()}
    assert sorted(rms) == [last - 1, last]
    # the kept round is the one whose draws fitted better; the RMS reported is not
    # that minimum but the check at 16 fresh draws of the kept posterior
    src = slip["check_after_draws"]
    assert src["draws"] == "fresh" and src["n_draws"] == 16
    assert src["selection_rms_mm"] == pytest.approx(min(rms.values()), rel=1e-12)
    assert slip["check_after"]["residual_rms_mm"] != pytest.approx(min(rms.values()), rel=1e-9)
    assert slip["check_after"]["residual_rms_spread"]["n_draws"] == 16 - src["n_failed"]
    assert any("fresh posterior draws solved for this report only" in w
               for w in d["plain_words"])
    reported = slip["reported_round"]
    if rms[last - 1] < rms[last]:
        assert reported == last - 1
        assert slip["log_evidence"] == pytest.approx(slip["rounds"][reported]["log_evidence"],
                                                     abs=1e-9)
        assert slip["particles"].endswith(f"active/{reported}/particles.h5")
        assert any(f"round {reported}'s posterior is reported" in w for w in d["plain_words"])
    else:
        assert reported is None
        # the last round's posterior: its own file, or the result's full search of the
        # surrogate's choices beside the rounds when the last round refitted them
        assert slip["particles"].endswith((f"active/{last}/particles.h5",
                                           "base_slip/particles.h5"))


@pytest.mark.slow
def test_concealed_growth_on_the_fsi_model(tmp_path):
    """End to end on the coarse FSI mesh (about 8 min on 2 cores): data with a hidden
    2 % growth at three loadings; the diagnosis must name growth and the extended
    model must fit better. Run with ``pytest -m slow``."""
    pytest.importorskip("ngsolve")
    import shutil

    from _workflow_helpers import REPO

    cfg_dir = tmp_path / "config"
    (cfg_dir / "concealed").mkdir(parents=True)
    shutil.copy(REPO / "config" / "config.yaml", cfg_dir / "config.yaml")
    for name in ("common", "growth"):
        shutil.copy(REPO / "config" / "concealed" / f"{name}.yaml",
                    cfg_dir / "concealed" / f"{name}.yaml")
    smk(tmp_path, "--configfile", "config/concealed/common.yaml",
        "config/concealed/growth.yaml", timeout=3000)
    d = json.loads((tmp_path / "results" / "concealed_growth" / "diagnosis" /
                    "diagnosis.json").read_text())
    assert not d["check"]["adequate"]
    assert d["attribution"]["ranking"][0]["candidate"] == "growth"
    assert d["chosen_model"] == "growth"
    growth = next(e for e in d["extended"] if e["candidate"] == "growth")
    assert growth["check_after"]["residual_rms_mm"] < 0.5 * d["check"]["residual_rms_mm"]
    assert growth["phi_mean"] == pytest.approx(0.02, rel=0.2)


@pytest.mark.extended
def test_two_hidden_effects_are_found_and_modelled_together(tmp_path, concealed):
    """A hidden base slip and a hidden prestrain at once: both are selected, the joint
    extension (both phi calibrated together) is the chosen model and fits to the noise,
    and the verdict names both (session measurements: RMS 7.5 -> 1.1-1.6 um, noise 1 um)."""
    cfg = {**concealed, "study": "analytic_two_effects",
           "observations": {**concealed["observations"],
                            "hidden": {"base_slip": 0.01, "prestrain": 0.02}},
           "diagnose": {**concealed["diagnose"], "n_extend": 1}}
    d, _ = _diagnosis(tmp_path, cfg)
    assert sorted(d["attribution"]["selected"]) == ["base_slip", "prestrain"]
    joint = next(e for e in d["extended"] if len(e["members"]) == 2)
    assert d["chosen_model"] == joint["candidate"]
    assert d["verdict"] == f"mismatch explained by {joint['candidate']}"
    assert joint["explains"]
    after = joint["check_after"]
    # the real solves at the joint posterior's draws pass the predictive check, and
    # their residual is near the noise: the RMS over 16 draws of this posterior
    # varies with the draws (1.14, 1.43 and 1.61 um in three runs whose posteriors
    # agree within 0.1 sd: linear inputs, ard false, log inputs), so 2 x noise,
    # against the base model's 7.5 um
    assert after["adequate"]
    assert after["residual_rms_mm"] <= 2.0 * after["sigma_mm"]
    # the truth within 3 posterior sd of each phi (one seed)
    for name, truth in (("base_slip", 0.01), ("prestrain", 0.02)):
        phi = joint["phi"][name]
        assert abs(phi["mean"] - truth) <= 3 * phi["std"], (name, phi)


@pytest.mark.extended
def test_a_misregistration_is_named_not_blamed_on_physics(tmp_path, concealed):
    """No hidden physics, the observed interfaces shifted by (6, -4) um and rotated by
    10 mrad: the misregistration is found, the registered observations against the
    jointly re-fitted base model fit to the noise, and the verdict says it is not
    physics. (The rotation trades off partly against E and nu in this model, so the
    estimate of the transform is not checked, only what it explains.)"""
    from bayescalib.diagnosis.stage import MISREGISTERED

    # the check after the re-fit draws from the joint fit's own (Laplace) posterior: with
    # the base posterior's draws moved along instead, it depended on how that posterior
    # had absorbed the misplacement (2.0 um against 1 um noise with the fitted nugget)
    cfg = {**concealed, "study": "analytic_misregistered",
           "observations": {**concealed["observations"], "hidden": {},
                            "misregistration": {"shift_x": 0.006, "shift_y": -0.004,
                                                "rotation": 0.01}},
           "diagnose": {**concealed["diagnose"], "n_extend": 0}}
    d, _ = _diagnosis(tmp_path, cfg)
    assert d["check"]["adequate"] is False
    reg = d["registration"]
    assert reg["significant"] and reg["explains"] and reg["draws_after"] == "laplace"
    assert reg["check_after"]["residual_rms_mm"] <= 1.5 * reg["check_after"]["sigma_mm"]
    # the re-fitted base parameters are closer to the truth than the biased posterior
    assert abs(reg["refit_parameters"]["E"] - 400.0) < abs(d["posterior_mean"]["E"] - 400.0)
    assert d["verdict"] == MISREGISTERED
    assert any("not physics" in line for line in d["plain_words"])
