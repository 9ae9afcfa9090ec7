"""Several loadings per design point (one observation snapshot per loading), on the
analytic stand-in model: the series, its run record, the synthetic observation set
with a hidden effect, the discrepancy summed over snapshots, and config checks."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml
from _workflow_helpers import DATA

from bayescalib.config import ConfigError
from bayescalib.io.observation_store import read_observations
from bayescalib.io.runrecord import read_run
from bayescalib.models.analytic import interface as analytic
from bayescalib.models.forward import PythonModel, loading_labels, solve_point, solve_series
from bayescalib.stages.discrepancy import discrepancy
from bayescalib.stages.errors import PipelineError
from bayescalib.stages.observe import observe
from bayescalib.study import Study

FM = {"type": "python", "python": {"function": "bayescalib.models.analytic:interface"},
      "loadings": {"parameter": "V", "nominal": 100.0, "factors": [0.0, 0.5, 1.0]}}
TRUTH = {"E": 400.0, "nu": 0.3}
MEASURE = {"sigma_w": 0.005}  # the options of measure.rkhs
LIK = {"sigma_n2": 0.0005}


def _observations(section):
    """A validated observations section (stages trust the validated config)."""
    from bayescalib.config import validate

    return validate({"observations": section}, "measures")["observations"]



def test_series_solves_each_loading_at_factor_times_nominal():
    res = solve_series(PythonModel(FM["python"]["function"]), TRUTH, FM["loadings"])
    assert res.ok
    assert [ld.label for ld in res.loadings] == loading_labels([0.0, 0.5, 1.0])
    for ld in res.loadings:
        expected = analytic({**TRUTH, "V": 100.0 * ld.factor})["current"]
        np.testing.assert_array_equal(ld.current, expected)
        assert ld.value == pytest.approx(100.0 * ld.factor)
    # the primary interface is the nominal loading; the nominal is recorded
    np.testing.assert_array_equal(res.interface_current, res.loadings[2].current)
    assert res.parameters["V"] == 100.0


def test_single_loading_is_the_plain_solve():
    model = PythonModel(FM["python"]["function"])
    a = solve_series(model, TRUTH, {"factors": [1.0]})
    b = model.solve(TRUTH)
    assert not a.loadings
    np.testing.assert_array_equal(a.interface_current, b.interface_current)


def test_a_failed_loading_fails_the_point_and_names_the_loading():
    model = PythonModel(FM["python"]["function"], {"fail_below_E": 130.0})
    res = solve_series(model, {"E": 120.0, "nu": 0.3}, FM["loadings"])
    assert not res.ok and "loading load_0" in res.reason


def test_run_record_keeps_the_loadings(tmp_path):
    res = solve_point(FM, TRUTH, tmp_path / "0.h5", isolate=False)
    back = read_run(tmp_path / "0.h5")
    assert [ld.label for ld in back.loadings] == [ld.label for ld in res.loadings]
    for a, b in zip(back.loadings, res.loadings):
        np.testing.assert_array_equal(a.current, b.current)
        assert (a.factor, a.value) == (b.factor, b.value)


def test_hidden_effect_series_observation_and_summed_likelihood(tmp_path):
    # synthetic data with a hidden base slip, at three loadings
    hidden = {"base_slip": 0.01}
    solve_point(FM, {**TRUTH, **hidden}, tmp_path / "truth.h5", isolate=False)
    observe(_observations({"source": "synthetic", "hidden": hidden}),
            tmp_path / "obs.h5", ground_truth_run=tmp_path / "truth.h5")
    obs = read_observations(tmp_path / "obs.h5")
    assert obs.labels == loading_labels([0.0, 0.5, 1.0])
    assert obs.loads == pytest.approx([0.0, 50.0, 100.0])
    assert obs.meta["hidden"] == hidden
    # the base model at the truth misses the slip at the loaded snapshots only
    solve_point(FM, TRUTH, tmp_path / "0.h5", isolate=False)
    rec = discrepancy(tmp_path / "0.h5", tmp_path / "obs.h5", "rkhs", MEASURE, LIK,
                      tmp_path / "d.json")
    lls = [s["loglik"] for s in rec["snapshots"]]
    D = [s["D"] for s in rec["snapshots"]]
    assert rec["loglik"] == pytest.approx(sum(lls))
    assert D[0] == pytest.approx(0.0, abs=1e-12)  # no flow: no slip, no mismatch
    assert 0.0 < D[1] < D[2]  # the slip grows with the load
    assert lls[2] < lls[1] < lls[0]
    # the model with the hidden effect reproduces every snapshot
    solve_point(FM, {**TRUTH, **hidden}, tmp_path / "1.h5", isolate=False)
    rec = discrepancy(tmp_path / "1.h5", tmp_path / "obs.h5", "rkhs", MEASURE, LIK,
                      tmp_path / "d1.json")
    assert max(s["D"] for s in rec["snapshots"]) == pytest.approx(0.0, abs=1e-9)


def test_snapshot_count_must_match_the_loadings(tmp_path):
    solve_point(FM, TRUTH, tmp_path / "truth.h5", isolate=False)
    observe(_observations({"source": "synthetic"}), tmp_path / "obs.h5", ground_truth_run=tmp_path / "truth.h5")
    two = {**FM, "loadings": {**FM["loadings"], "factors": [0.5, 1.0]}}
    solve_point(two, TRUTH, tmp_path / "0.h5", isolate=False)
    with pytest.raises(PipelineError, match="2 loadings but the observation set"):
        discrepancy(tmp_path / "0.h5", tmp_path / "obs.h5", "rkhs", MEASURE, LIK,
                    tmp_path / "d.json")


@pytest.fixture()
def study_cfg():
    cfg = yaml.safe_load((DATA / "analytic_study.yaml").read_text())
    cfg["forward_model"]["loadings"] = copy.deepcopy(FM["loadings"])
    return cfg


def test_study_with_loadings_is_valid_and_the_solve_depends_on_them(study_cfg):
    study = Study(study_cfg)
    assert study.forward_section()["loadings"]["factors"] == [0.0, 0.5, 1.0]
    single = copy.deepcopy(study_cfg)
    del single["forward_model"]["loadings"]
    assert "loadings" not in Study(single).forward_section()


@pytest.mark.parametrize("change, message", [
    (lambda c: c["forward_model"]["loadings"].update(nominal=None),
     "forward_model.loadings.nominal is required"),
    (lambda c: c["forward_model"]["loadings"].update(factors=[0.5, 0.5]),
     "duplicate factors"),
    (lambda c: c["forward_model"]["loadings"].update(factors=[-1.0, 1.0]),
     "forward_model.loadings.factors"),
    (lambda c: c["observations"].update(source="files", files=[{"path": "a.csv"}]),
     "observations.files has 1 file(s) but forward_model.loadings.factors has 3"),
])
def test_bad_loadings_name_the_key(study_cfg, change, message):
    change(study_cfg)
    with pytest.raises(ConfigError) as exc:
        Study(study_cfg)
    assert message in str(exc.value)


def test_hidden_keys_are_checked_against_the_fsi_config():
    pytest.importorskip("ngsolve")
    cfg = yaml.safe_load((DATA / "analytic_study.yaml").read_text())
    cfg["forward_model"] = {"type": "fsi", "fsi": {"mesh": {"preset": "coarse"}}}
    for p in cfg["parameters"]:
        p["target"] = f"material.{p['name']}"
    cfg["observations"]["hidden"] = {"physics.growth.enabled": True, "physics.growth.phi": 0.03}
    study = Study(cfg)
    assert study.ground_truth_point()["physics.growth.phi"] == 0.03
    cfg["observations"]["hidden"] = {"physics.groth.phi": 0.03}
    with pytest.raises(ConfigError, match="observations.hidden: .*unknown key 'physics.groth'"):
        Study(cfg)
    cfg["observations"]["hidden"] = {"physics.growth.phi": 0.03}
    with pytest.raises(ConfigError, match="physics.growth.enabled is false"):
        Study(cfg)


@pytest.mark.workflow
def test_workflow_with_three_loadings_and_a_hidden_effect(tmp_path, study_cfg):
    import json

    from _workflow_helpers import setup_study, smk

    study_cfg["observations"]["hidden"] = {"base_slip": 0.005}
    study_cfg["plots"]["formats"] = ["png"]
    setup_study(tmp_path, study_cfg)
    smk(tmp_path)
    root = tmp_path / "results" / "analytic"
    obs = read_observations(root / "observations" / "observations.h5")
    assert obs.labels == loading_labels([0.0, 0.5, 1.0])
    run = read_run(root / "runs" / "0.h5")
    assert len(run.loadings) == 3
    summary = json.loads((root / "summary.json").read_text())
    assert np.isfinite(summary["log_evidence"])
