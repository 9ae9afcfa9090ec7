"""A study on real recordings (observations.source: files, no ground truth) says
nothing of a ground truth: no solve at one, no figure, caption or report section of
one, and no ground_truth in summary.json or on the report's front page. What a
mechanician expects instead of the truth's fields, the flow and deformation of the
calibrated model, is the fields figure: a solve at the posterior mean. The synthetic
study keeps its rules and outputs (the ground truth's solve and fields)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from types import SimpleNamespace

import jinja2
import numpy as np
import pytest
from _workflow_helpers import REPO
from _workflow_helpers import setup_study as _setup
from _workflow_helpers import smk as _smk

CAPTIONS = REPO / "workflow" / "report"
FSI_STUDY = {  # the smoke study's model, a small fixed design (every rule in the dry run)
    "study": "scan",
    "forward_model": {"type": "fsi", "time_limit_s": 60, "fsi": {"mesh": {"preset": "coarse"}}},
    "parameters": [
        {"name": "E", "unit": "Pa", "target": "material.E",
         "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}},
        {"name": "nu", "unit": "-", "target": "material.nu",
         "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45}},
    ],
    "measures": ["rkhs"],
    "measure": {"rkhs": {"sigma_w": 0.005}},
    "likelihood": {"sigma_n": 0.02},
    "design": {"strategy": "fixed", "n_train": 8, "seed": 1},
    "posterior_check": {"draws": 0},
    "diagnose": {"enabled": False},
    "plots": {"n_interface_samples": 2, "formats": ["png"], "dpi": 80},
}


def _scan(tmp: Path) -> Path:
    """A stand-in recording: the undeformed half ellipse of the default geometry, mm."""
    x = np.linspace(0.7, 1.3, 41)
    y = 0.4 * np.sqrt(np.clip(1 - ((x - 1.0) / 0.3) ** 2, 0, None))
    path = tmp / "scan.csv"
    np.savetxt(path, np.column_stack([x, y]), delimiter=",", header="x,y", comments="")
    return path


def _real(tmp: Path) -> dict:
    return {**FSI_STUDY, "observations": {
        "source": "files", "domain": [[-0.5, 3.0], [-0.1, 1.0]],
        "files": [{"path": str(_scan(tmp)), "units": "mm"}]}}


def _synthetic() -> dict:
    params = [dict(p) for p in FSI_STUDY["parameters"]]
    params[0]["ground_truth"], params[1]["ground_truth"] = 400.0, 0.3
    return {**FSI_STUDY, "parameters": params, "observations": {"source": "synthetic"}}


def _dry_run(tmp: Path, study: dict) -> str:
    _setup(tmp, study)
    proc = _smk(tmp, "-n", "-p")
    return proc.stdout + proc.stderr


def _jobs(text: str, rule: str) -> list[str]:
    """The dry run's job blocks of ``rule`` (header to the blank line after it)."""
    return re.findall(rf"^rule {rule}:\n(?:.+\n)+", text, flags=re.MULTILINE)


@pytest.mark.workflow
def test_a_study_on_real_data_solves_no_ground_truth_and_shows_the_posterior_means_fields(
        tmp_path):
    text = _dry_run(tmp_path, _real(tmp_path))
    # no rule, file, log or benchmark of one (the parameters' ground_truth keys are null)
    assert not _jobs(text, "ground_truth")
    assert not re.search(r"ground_truth(_run)?\.(h5|vtu|log|tsv)", text)
    (solve,) = _jobs(text, "posterior_mean_solve")
    assert "results/scan/rkhs/posterior.json" in solve
    assert "posterior_mean_solve" in solve and "results/scan/posterior_mean/fields.vtu" in solve
    (fig,) = _jobs(text, "fig_fields")
    # the job's values travel as one JSON document (not shown by a dry run): its inputs
    assert re.search(r"input: \S*posterior_mean/fields.vtu, \S*posterior_mean/run.h5", fig), fig


@pytest.mark.workflow
def test_a_synthetic_study_keeps_the_ground_truths_solve_and_fields(tmp_path):
    text = _dry_run(tmp_path, _synthetic())
    assert len(_jobs(text, "ground_truth")) == 1
    assert "posterior_mean" not in text
    (fig,) = _jobs(text, "fig_fields")
    # the job's values travel as one JSON document (not shown by a dry run): its inputs
    assert re.search(r"input: \S*observations/ground_truth.vtu, \S*ground_truth_run.h5", fig), fig


# ---- captions and the front page (rendered as Snakemake's report renders them)

def _render(name: str, *, truth: bool, synthetic: bool, front_page=None) -> str:
    config = {"study": "scan", "front_page": front_page,
              "report_flags": {"ground_truth": truth, "synthetic": synthetic}}
    env = jinja2.Environment(undefined=jinja2.StrictUndefined)
    snakemake = SimpleNamespace(config=config, wildcards=SimpleNamespace(measure="rkhs"))
    return env.from_string((CAPTIONS / name).read_text()).render(snakemake=snakemake)


def _front_page(truth: bool) -> dict:
    row = ["E", "Pa", "401", "402", "12", "[380, 420]"] + (["400"] if truth else [])
    return {"line": "bayescalib scan: E = 402 +- 12 Pa", "reason": "fixed design",
            "rows": [row], "truth_known": truth, "converged": None, "measure": "rkhs",
            "fit": "", "fit_consistent": None, "check": "", "check_confirmed": None}


CAPTION_FILES = sorted(p.name for p in CAPTIONS.glob("*.rst"))


@pytest.mark.parametrize("name", CAPTION_FILES)
def test_no_caption_of_a_study_without_ground_truth_speaks_of_one(name):
    text = _render(name, truth=False, synthetic=False, front_page=_front_page(False))
    assert "truth" not in text.lower(), text


@pytest.mark.parametrize("name", ["response.rst", "interfaces.rst", "particles.rst",
                                  "rounds.rst", "joint.rst", "marginals.rst", "pairs.rst",
                                  "summary.rst", "fields.rst", "workflow.rst"])
def test_the_captions_of_a_synthetic_study_name_its_ground_truth(name):
    text = _render(name, truth=True, synthetic=True, front_page=_front_page(True))
    assert "ground truth" in text.lower().replace("-", " "), text


def test_the_fields_caption_of_real_data_says_posterior_mean():
    text = _render("fields.rst", truth=False, synthetic=False)
    assert text.startswith("Fields at the posterior mean")


def test_the_front_page_table_has_a_truth_column_only_with_a_truth():
    for truth in (False, True):
        text = _render("workflow.rst", truth=truth, synthetic=truth, front_page=_front_page(truth))
        table = text[text.index(".. list-table::"):text.index("Method:")]
        rows = re.split(r"\n\s*\* - ", table)[1:]  # header and one parameter
        cells = [1 + len(re.findall(r"^\s+- ", r, flags=re.MULTILINE)) for r in rows]
        assert cells == [7 if truth else 6] * 2, (truth, table)


# ---- summary.json, the run's last line, `bayescalib summary`

def test_summary_json_of_real_data_has_no_ground_truth_key(tmp_path):
    from bayescalib.stages.summary import front_page, run_line

    base = {"study": "scan", "measure": "rkhs",
            "parameters": [{"name": "E", "unit": "Pa"}], "map": {"E": 401.0},
            "posterior_mean": {"E": 402.0}, "posterior_sd": {"E": 12.0},
            "posterior_cov": [[144.0]], "credible_intervals": {"E": {"0.9": [380.0, 420.0]}},
            "n_train": 8, "n_failed": 0, "design": {"strategy": "fixed", "n_solves": 8,
                                                   "converged": None, "reason": "fixed"}}
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(base))
    fp = front_page(path)
    assert fp["truth_known"] is False and fp["rows"] == [
        ["E", "Pa", "401", "402", "12", "[380, 420]"]]
    assert "truth" not in run_line(base).lower()
    path.write_text(json.dumps({**base, "ground_truth": {"E": 400.0}}))
    fp = front_page(path)
    assert fp["truth_known"] is True and fp["rows"][0][-1] == "400"


def test_the_fields_figure_of_a_failed_solve_at_the_posterior_mean_says_why(tmp_path):
    from bayescalib.io.runrecord import write_run
    from bayescalib.models.forward import failed_result
    from bayescalib.stages.figures import field_figure

    run = tmp_path / "run.h5"
    write_run(run, failed_result({"material.E": 412.0, "material.nu": 0.31},
                                 "Newton did not converge"))
    (tmp_path / "fields.vtu").write_bytes(b"")
    files = field_figure(tmp_path / "fields.vtu", run, {"formats": ["png"], "dpi": 60},
                         tmp_path / "fields", at="posterior_mean",
                         parameters=FSI_STUDY["parameters"])
    assert [Path(f).name for f in files] == ["fields.png"] and Path(files[0]).stat().st_size


def test_the_solve_at_the_posterior_mean_is_at_the_mean_keyed_by_target(tmp_path):
    from bayescalib.stages.figures import posterior_mean_point

    post = tmp_path / "posterior.json"
    post.write_text(json.dumps({"mean": {"E": 402.5, "nu": 0.25}}))
    assert posterior_mean_point(post, FSI_STUDY["parameters"]) == {
        "material.E": 402.5, "material.nu": 0.25}
