"""The diagnose stage end to end on the analytic stand-in model (known missing term):
a hidden base slip must be located, attributed to the right candidate, and modelled
with a clear Bayes factor; without a hidden effect nothing may be claimed."""

from __future__ import annotations

import json

import pytest
import yaml
from _workflow_helpers import DATA, setup_study, smk

pytestmark = pytest.mark.workflow


@pytest.fixture(scope="module")
def concealed():
    return yaml.safe_load((DATA / "analytic_concealed.yaml").read_text())


def _diagnosis(tmp, cfg):
    setup_study(tmp, cfg)
    smk(tmp)
    root = tmp / "results" / cfg["study"]
    return json.loads((root / "diagnosis" / "diagnosis.json").read_text()), root


def test_hidden_slip_is_located_named_modelled_and_improves_the_fit(tmp_path, concealed):
    d, root = _diagnosis(tmp_path, concealed)
    assert d["check"]["adequate"] is False
    assert d["check"]["located"], "no mismatch interval located"
    assert d["attribution"]["ranking"][0]["candidate"] == "base_slip"
    assert d["attribution"]["selected"] == ["base_slip"]
    assert d["chosen_model"] == "base_slip"
    slip = next(e for e in d["extended"] if e["candidate"] == "base_slip")
    assert slip["log_bayes_factor"] > 3.0  # strong evidence (B > 20)
    assert slip["check_after"]["residual_rms_mm"] < 0.6 * d["check"]["residual_rms_mm"]
    for fam in ("residuals", "interface_residual", "candidates"):
        assert (root / "figures" / "diagnosis" / f"{fam}.png").stat().st_size > 1000
    html = (root / "diagnosis" / "diagnosis.html").read_text()
    assert "base_slip" in html and "Verdict" in html


def test_no_hidden_effect_no_claim(tmp_path, concealed):
    cfg = {**concealed, "study": "analytic_null",
           "observations": {**concealed["observations"], "hidden": {}}}
    d, _ = _diagnosis(tmp_path, cfg)
    assert d["verdict"] == "no significant mismatch"
    assert d["extended"] == [] and d["chosen_model"] == "base"
