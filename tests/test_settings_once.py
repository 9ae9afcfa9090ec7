"""Settings are built once (issue 37, item 3): a setting's default lives in the schemas
only, a parameter's target is filled once when the study is read, and the GP
convergence study fits the study's own surrogate.

- No ``.get("<key>", <default>)`` on a config section in src/, scripts/ or workflow/:
  the schemas fill every documented key (:func:`bayescalib.config.validate`), so a
  second default in the code could only disagree with them. The scan flags the keys the
  schemas define; :data:`ALLOWED` lists the dicts that are not config sections.
- :func:`bayescalib.inference.gp.fit.fit_gp` has no default of its own for a setting
  of the ``surrogate`` section: the model's choices are required, the optimizer's
  settings left out are the schema's; :func:`fit_from_config` passes all of them.
"""

from __future__ import annotations

import inspect
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from bayescalib.config import defaults, load_yaml, merge_layers
from bayescalib.inference.design import sobol_design, sobol_test_points
from bayescalib.inference.gp import GPSurrogate, fit_from_config, surrogate_settings
from bayescalib.inference.gp import fit as gp_fit
from bayescalib.inference.gp import selection as gp_selection

ROOT = Path(__file__).resolve().parents[1]
SCHEMAS = ROOT / "src" / "bayescalib" / "schemas"

#: (file, key) -> why a ``.get(key, default)`` there is not a default of a config section
ALLOWED: dict[tuple[str, str], str] = {
    ("src/bayescalib/config_reference.py", "description"):
        "a schema node (the reference is written from the schemas), not a config",
    ("src/bayescalib/geometry/registration.py", "shift_x"):
        "a rigid transform (observations.misregistration or a fitted one): a part left out "
        "is no misplacement; the schema gives none so that studies without it keep "
        "their cache keys",
    ("src/bayescalib/geometry/registration.py", "shift_y"): "as shift_x",
    ("src/bayescalib/geometry/registration.py", "rotation"): "as shift_x",
    ("src/bayescalib/geometry/registration.py", "scale"): "as shift_x",
    ("src/bayescalib/diagnosis/stage.py", "shift_x"):
        "the registration's estimate (a result: the parts it fitted)",
    ("src/bayescalib/diagnosis/stage.py", "shift_y"): "as shift_x",
    ("src/bayescalib/diagnosis/stage.py", "name"):
        "a posterior check record read back (its noise model, absent in older records)",
    ("src/bayescalib/diagnosis/stage.py", "n_draws"):
        "an extension's record of its check draws read back",
    ("src/bayescalib/diagnosis/report.py", "unit"):
        "a row of diagnosis.json's attribution ranking read back",
    ("src/bayescalib/stages/summary.py", "unit"):
        "summary.json read back (run_line, the report's table)",
    ("src/bayescalib/stages/summary.py", "design"):
        "the summary's extra records (the design summary of a run), not a config section",
    ("src/bayescalib/cli/summary.py", "unit"): "summary.json read back",
    ("src/bayescalib/inference/gp/store.py", "kernel"):
        "an attribute of a surrogate file written before the kernel was recorded",
    ("src/bayescalib/models/fsi/model.py", "fsi"):
        "the raw config before validation: a type check of the section",
}

_GET = re.compile(r"""\.get\(\s*(["'])([A-Za-z_]\w*)\1\s*,""")


def _schema_keys() -> set[str]:
    keys: set[str] = set()

    def walk(node):
        if isinstance(node, dict):
            props = node.get("properties")
            if isinstance(props, dict):
                keys.update(props)
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    for path in SCHEMAS.glob("*.schema.yaml"):
        walk(yaml.safe_load(path.read_text()))
    return keys


def _sources() -> list[Path]:
    return sorted([*ROOT.glob("src/**/*.py"), *ROOT.glob("scripts/**/*.py"),
                   *ROOT.glob("workflow/**/*.smk"), *ROOT.glob("workflow/**/*.py"),
                   ROOT / "Snakefile"])


def _defaults_in_code() -> list[tuple[str, int, str, str]]:
    """(file, line, key, text) of every ``.get("<key>", <default>)`` whose key is a key
    of the schemas."""
    keys = _schema_keys()
    out = []
    for path in _sources():
        rel = path.relative_to(ROOT).as_posix()
        for i, line in enumerate(path.read_text().splitlines(), 1):
            for m in _GET.finditer(line):
                if m.group(2) in keys:
                    out.append((rel, i, m.group(2), line.strip()))
    return out


def test_no_default_outside_the_schemas():
    """A config section is read as ``section[key]`` (the schema filled it) or, for an
    optional key without a schema default, ``section.get(key)``; never with a default of
    the code's own."""
    found = [f"{f}:{i}: {text}" for f, i, key, text in _defaults_in_code()
             if (f, key) not in ALLOWED]
    assert not found, ("defaults outside the schemas (give the key a default in its "
                       "schema and read section[key], or add the dict to ALLOWED with "
                       "the reason it is not a config section):\n" + "\n".join(found))


def test_the_allow_list_has_no_stale_entries():
    seen = {(f, key) for f, _, key, _ in _defaults_in_code()}
    stale = sorted(set(ALLOWED) - seen)
    assert not stale, f"ALLOWED entries that match nothing any more: {stale}"


def test_the_scan_sees_a_default_outside_the_schemas(tmp_path, monkeypatch):
    """The scan itself: a rule file reading a config key with a default is flagged."""
    (tmp_path / "workflow" / "rules").mkdir(parents=True)
    (tmp_path / "workflow" / "rules" / "x.smk").write_text(
        'SYN = obs.get("source", "synthetic") == "synthetic"\n')
    (tmp_path / "Snakefile").write_text("")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert [(f, k) for f, _, k, _ in _defaults_in_code()] == [("workflow/rules/x.smk", "source")]


# ------------------------------------------------------------------------ fit_gp
#: fit_gp's settings that the surrogate section holds (output: ``warp``)
SECTION_SETTINGS = {"kernel", "nugget", "mean", "ard", "warp", "optimizer", "restarts", "seed",
                    "mean_offset_factor", "nugget_factor", "nugget_floor"}


def test_fit_gp_has_no_default_of_its_own_for_a_surrogate_setting():
    params = inspect.signature(gp_fit.fit_gp).parameters
    # the model's choices (the section decides some by a search one fit cannot make)
    for name in ("kernel", "nugget", "mean", "ard"):
        assert params[name].default is inspect.Parameter.empty, name
    # the optimizer's settings and the output: None, i.e. the schema's / given with a bound
    for name in SECTION_SETTINGS - {"kernel", "nugget", "mean", "ard"}:
        assert params[name].default is None, name
    assert set(defaults("inference", "surrogate")) >= SECTION_SETTINGS - {"warp"}


def test_fit_gp_needs_the_output_with_a_bound():
    X = sobol_design(np.array([[0.0, 1.0], [0.0, 1.0]]), 8, 0)
    with pytest.raises(ValueError, match="warp must be given with a bound"):
        gp_fit.fit_gp(X, -np.sum(X**2, axis=1), kernel="matern32", nugget="fixed",
                   mean="constant", ard=False, bound=0.0)


def test_fit_gp_takes_the_schemas_optimizer_settings(monkeypatch):
    """Left out, the optimizer's settings are the schema's, read from it (not copied):
    a schema with other defaults gives a fit with those."""
    X = sobol_design(np.array([[0.0, 1.0], [0.0, 1.0]]), 12, 0)
    y = -np.sum((X - 0.4) ** 2, axis=1)
    kw = {"kernel": "matern32", "nugget": "fixed", "mean": "constant", "ard": False}
    schema = defaults("inference", "surrogate")
    plain = gp_fit.fit_gp(X, y, **kw)
    spelled = gp_fit.fit_gp(X, y, **kw, **{k: schema[k] for k in (
        "optimizer", "restarts", "seed", "mean_offset_factor", "nugget_factor", "nugget_floor")})
    assert plain.restarts == schema["restarts"]
    assert plain.hyperparameters == spelled.hyperparameters
    other = {**schema, "restarts": 1, "nugget_factor": 1e-3}
    monkeypatch.setattr(gp_fit, "defaults", lambda name, definition: dict(other))
    changed = gp_fit.fit_gp(X, y, **kw)
    assert changed.restarts == 1
    assert changed.nugget == pytest.approx(1e-3 * float(np.ptp(y)))


def test_fit_from_config_passes_every_setting_of_the_section(monkeypatch):
    calls = []

    def recording(X, y, **kw):
        calls.append(kw)
        raise RuntimeError("recorded")

    monkeypatch.setattr(gp_selection, "fit_gp", recording)
    X = sobol_design(np.array([[0.0, 1.0], [0.0, 1.0]]), 8, 0)
    with pytest.raises(RuntimeError, match="every GP surrogate fit failed"):
        fit_from_config(X, -np.sum(X**2, axis=1), surrogate_settings(restarts=1),
                        np.array([[0.0, 1.0], [0.0, 1.0]]), bound=0.0)
    assert calls
    for kw in calls:
        missing = SECTION_SETTINGS - {k for k, v in kw.items() if v is not None}
        assert not missing, missing


# ------------------------------------------------------------------- targets
def test_a_parameter_without_a_target_gets_its_name_once():
    """The study fills every parameter's target when it reads its config (the name where
    none is given); the rest of the code reads ``p["target"]``."""
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.study import Study

    cfg = load_yaml(ROOT / "tests" / "data" / "analytic_study.yaml")
    params = [dict(p) for p in cfg["parameters"]]
    del params[1]["target"]
    study = Study(merge_layers([cfg, {"parameters": params}]))
    assert [p["target"] for p in study.config["parameters"]] == ["E", "nu"]
    assert study.targets() == ["E", "nu"] and set(study.ground_truth()) == {"E", "nu"}
    assert ParameterSpace.from_config(params).parameters[1].target == "nu"


# ---------------------------------------------------------------- convergence
BOX = np.array([[100.0, 800.0], [-0.8, 0.45]])


def _loglik(X):
    """A Gaussian log-likelihood with its upper bound 0 (an analytic study's)."""
    u = (X - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
    return -0.5 * (((u[:, 0] - 0.45) / 0.15) ** 2 + ((u[:, 1] - 0.6) / 0.25) ** 2
                   + 1.2 * (u[:, 0] - 0.45) * (u[:, 1] - 0.6) / 0.04)


def test_the_convergence_study_fits_the_studys_surrogate(tmp_path):
    """At the full training set the GP of the convergence study (paper Sec. 4.3) is the
    study's surrogate: the same data, the likelihood's bound, the kernel, output, frame,
    inputs, mean and nugget of the surrogate section (before issue 37 it was a Matérn 3/2
    of L without the bound, whatever the section said)."""
    from bayescalib.io.training import write_training
    from bayescalib.stages.convergence import convergence
    from bayescalib.stages.files import read_json
    from bayescalib.stages.surrogate import train_surrogate

    n, n_test = 24, 8
    X = np.vstack([sobol_design(BOX, n, 1), sobol_test_points(BOX, n, n_test, 1)])
    L = _loglik(X)
    training = tmp_path / "training.h5"
    write_training(training, X, L, -L, np.ones(len(L), bool), [""] * len(L), ["E", "nu"], n,
                   bound=np.zeros(len(L)))
    parameters = [
        {"name": "E", "unit": "Pa", "target": "E", "prior": {"type": "uniform", "lo": 100.0,
                                                            "hi": 800.0}, "bounds": [100.0, 800.0]},
        {"name": "nu", "unit": "-", "target": "nu", "prior": {"type": "uniform", "lo": -0.8,
                                                             "hi": 0.45}, "bounds": [-0.8, 0.45]}]
    # settings the old convergence stage dropped: a kernel other than Matérn 3/2, the
    # output chosen with the bound, one length scale per input, the fitted nugget
    section = surrogate_settings(kernel="rbf", output="auto", ard=True, frame="axes",
                                 inputs="linear", restarts=1)
    train_surrogate(training, section, parameters, tmp_path / "surrogate.h5")
    study_gp = GPSurrogate.load(tmp_path / "surrogate.h5", device="cpu")
    res = convergence(training, section, parameters, [12, n],
                      tmp_path / "convergence.json")
    # the GP measured at n is the study's: its error at the held-out points is the
    # study surrogate's (before issue 37 another GP's)
    err = np.linalg.norm(study_gp.predict(X[n:]) - L[n:])
    assert res["l2_error"][-1] == pytest.approx(err, rel=1e-9, abs=1e-12)
    full = res["surrogate"][-1]
    assert full["kernel"] == "RBF" and full["bound"] == 0.0 and full["ard"]
    assert full["nugget_mode"] == "fit"
    assert full == study_gp.hyperparameters
    assert res["n_train"] == [12, n] and res["n_used"] == [12, n]
    assert read_json(tmp_path / "convergence.json")["surrogate"][-1] == full
