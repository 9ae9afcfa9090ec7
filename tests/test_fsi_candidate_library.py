"""The library of candidate physics is wired through config, diagnosis and docs: every
candidate of bayescalib.models.fsi.physics has a schema section (defaults switched
off, phi = 0), a default prior range in the diagnosis that contains its typical step,
and is offered to the diagnosis of an fsi study. No solver needed."""

from __future__ import annotations

from pathlib import Path

import pytest

from bayescalib.config import ConfigError, validate
from bayescalib.diagnosis.stage import resolve_candidates
from bayescalib.models.fsi.physics import CANDIDATES

README = Path(__file__).resolve().parents[1] / "README.md"
DIAGNOSE = validate({"study": "library"}, "study")["diagnose"]
PRIORS = DIAGNOSE["priors"]


def test_every_candidate_has_a_switched_off_schema_section_and_a_prior():
    physics = validate({}, "fsi")["physics"]
    assert set(physics) == set(CANDIDATES) == set(PRIORS)
    for name, cand in CANDIDATES.items():
        assert physics[name]["enabled"] is False and physics[name]["phi"] == 0.0
        lo, hi = PRIORS[name]
        assert lo < hi and lo <= cand.typical <= hi
        assert f"| `{name}` |" in README.read_text()


def test_the_permeable_biofilm_is_a_candidate_in_um2_offered_to_the_diagnosis():
    cand = CANDIDATES["permeability"]
    assert cand.key == "physics.permeability.phi" and cand.unit == "um^2"
    assert cand.lo == 0.0 and cand.typical > 0.0
    specs = {c.name: c for c in resolve_candidates({"type": "fsi", "fsi": {}}, DIAGNOSE)}
    spec = specs["permeability"]
    assert spec.target == "physics.permeability.phi"
    assert spec.switches == {"physics.permeability.enabled": True}
    assert list(spec.prior) == PRIORS["permeability"] and spec.prior[0] == 0.0
    # already switched on in the model being diagnosed: not offered again
    on = {"type": "fsi", "fsi": {"physics": {"permeability": {"enabled": True}}}}
    assert "permeability" not in {c.name for c in resolve_candidates(on, DIAGNOSE)}


def test_a_negative_permeability_is_rejected_naming_the_key():
    with pytest.raises(ConfigError, match="permeability"):
        validate({"physics": {"permeability": {"enabled": True, "phi": -1.0}}}, "fsi")


def test_a_widened_prior_range_reaches_the_candidate_and_a_reversed_one_is_rejected():
    wide = validate({"study": "s", "diagnose": {"priors": {"stiffening": [0.0, 400.0]}}},
                    "study")["diagnose"]
    specs = {c.name: c for c in resolve_candidates({"type": "fsi", "fsi": {}}, wide)}
    assert specs["stiffening"].prior == (0.0, 400.0)
    assert list(specs["growth"].prior) == PRIORS["growth"]  # the others keep their defaults
    with pytest.raises(ConfigError, match="diagnose.priors"):
        validate({"study": "s", "diagnose": {"priors": {"stiffness": [0.0, 1.0]}}}, "study")


def test_a_reversed_prior_range_is_rejected_naming_the_key():
    from bayescalib.study import Study

    cfg = {"study": "s", "diagnose": {"enabled": True, "priors": {"growth": [0.1, -0.1]}}}
    with pytest.raises(ConfigError, match=r"diagnose\.priors\.growth: lo must be < hi"):
        Study(cfg)
