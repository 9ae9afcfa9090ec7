"""The Snakemake workflow as users run it, on the analytic stand-in model.

Cache awareness is the contract here (issue: partial reruns): after a complete
run, a change of a GP, SMC, likelihood or plot setting reruns no forward solve;
growing the design from n to 2n solves exactly n new points; a forward-model
change reruns the solves; a run killed during the solves resumes without
redoing finished ones.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import yaml
from _workflow_helpers import REPO, run_and_kill
from _workflow_helpers import setup_study as _setup
from _workflow_helpers import smk as _smk

# fixtures base_study and done_run: tests/conftest.py

pytestmark = pytest.mark.workflow


def job_counts(tmp: Path, *extra: str) -> dict[str, int]:
    """Jobs a dry run would execute, per rule."""
    proc = _smk(tmp, "-n", *extra)
    text = proc.stdout + proc.stderr
    counts: dict[str, int] = {}
    if "Nothing to be done" in text:
        return counts
    block = text.split("Job stats:", 1)[1]
    for line in block.splitlines()[3:]:
        m = re.match(r"^(\w+)\s+(\d+)$", line.strip())
        if not m:
            if counts:
                break
            continue
        counts[m.group(1)] = int(m.group(2))
    counts.pop("total", None)
    return counts


def _with(study: dict, **changes) -> dict:
    out = json.loads(json.dumps(study))
    for dotted, value in changes.items():
        node = out
        keys = dotted.split("__")
        for k in keys[:-1]:
            node = node.setdefault(k, {})
        node[keys[-1]] = value
    return out


def _copy_run(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


def test_complete_run_writes_summary_with_contract_keys(done_run):
    summary = json.loads((done_run / "results" / "analytic" / "summary.json").read_text())
    for key in ("parameters", "map", "posterior_mean", "posterior_cov", "log_evidence",
                "n_train", "n_failed", "ground_truth", "figures"):
        assert key in summary, key
    assert [p["name"] for p in summary["parameters"]] == ["E", "nu"]
    assert summary["parameters"][0]["unit"] == "Pa"
    assert summary["n_train"] == 8
    # one block per thing: sd at top level, the interval type named, failures with
    # their reasons, the Laplace covariance with the Hessian's sign convention, and
    # per measure one compact line (the full analysis is in its posterior.json)
    assert set(summary["posterior_sd"]) == {"E", "nu"}
    assert summary["credible_interval_type"].startswith("equal-tailed")
    assert len(summary["failed_runs"]) == summary["n_failed"]
    for f in summary["failed_runs"]:
        assert f["reason"] and f["parameters"]["E"] < 130.0  # the model fails below 130 Pa
    assert "negative definite" in summary["laplace"]["hessian_convention"]
    assert "posterior" not in summary["measures"]["rkhs"]
    assert (done_run / summary["measures"]["rkhs"]["posterior_json"]).is_file()
    assert "gp_convergence" not in summary  # no convergence study ran
    # each solve's log says how it went
    text = (done_run / "results" / "analytic" / "logs" / "solve" / "0.log").read_text()
    assert "solve 0.h5: ok at E = " in text and "Newton iteration(s)" in text
    # every stage reports its job time, figures included (benchmark files of the rules)
    assert {"solve", "train_surrogate", "smc", "figures"} <= set(summary["timings_s"])
    for files in summary["figures"].values():
        for f in files:
            assert (done_run / f).is_file(), f
    assert job_counts(done_run) == {}


def test_every_result_file_is_readable_by_collaborators(done_run):
    """All result files get the permissions of a normally created file (0666 minus the
    umask), not the 0600 of a temporary file: others on a shared machine can read them."""
    import os
    import stat

    mask = os.umask(0)
    os.umask(mask)
    files = [f for f in (done_run / "results").rglob("*") if f.is_file()]
    assert len(files) > 20
    wrong = {str(f.relative_to(done_run)): oct(stat.S_IMODE(f.stat().st_mode)) for f in files
             if stat.S_IMODE(f.stat().st_mode) & 0o666 != 0o666 & ~mask}
    assert not wrong, wrong
    assert not [f for f in files if f.name.startswith(".") and ".tmp" in f.name]


@pytest.mark.parametrize(
    "change, expect_rerun, expect_zero",
    [
        ({"surrogate__restarts": 2}, {"train_surrogate", "smc"}, {"solve", "discrepancy"}),
        ({"smc__n_rej": 4}, {"smc", "marginalize"}, {"solve", "discrepancy", "train_surrogate"}),
        ({"likelihood__sigma_n2": 0.001}, {"discrepancy", "train_surrogate"}, {"solve"}),
        ({"measure__rkhs__sigma_w": 0.006}, {"discrepancy"}, {"solve"}),
        # the study uses the RKHS measure only: another measure's options rerun nothing
        ({"measure__euclidean__n_points": 12}, set(),
         {"solve", "discrepancy", "train_surrogate", "smc"}),
        ({"plots__dpi": 70}, {"fig_posterior", "fig_response"},
         {"solve", "discrepancy", "train_surrogate", "smc"}),
    ],
)
def test_downstream_change_reruns_no_solve(done_run, base_study, tmp_path, change, expect_rerun,
                                            expect_zero):
    tmp = _copy_run(done_run, tmp_path / "run")
    _setup(tmp, _with(base_study, **change))
    counts = job_counts(tmp)
    for rule in expect_zero:
        assert counts.get(rule, 0) == 0, (rule, counts)
    for rule in expect_rerun:
        assert counts.get(rule, 0) > 0, (rule, counts)


def test_doubling_the_design_solves_only_the_new_points(done_run, base_study, tmp_path):
    tmp = _copy_run(done_run, tmp_path / "run")
    _setup(tmp, _with(base_study, design__n_train=16))
    counts = job_counts(tmp)
    assert counts.get("solve") == 8
    assert counts.get("discrepancy") == 8


def test_forward_model_change_reruns_the_solves(done_run, base_study, tmp_path):
    tmp = _copy_run(done_run, tmp_path / "run")
    _setup(tmp, _with(base_study, forward_model__python__options={"fail_below_E": 130.0,
                                                                   "u0": 0.03}))
    counts = job_counts(tmp)
    assert counts.get("solve") == 8
    assert counts.get("ground_truth") == 1


def test_killed_run_resumes_without_redoing_finished_solves(base_study, done_run, tmp_path):
    study = _with(base_study, design__n_train=8,
                  forward_model__python__function="slow_model:interface")
    tmp = _setup(tmp_path / "run", study)
    runs = tmp / "results" / "analytic" / "runs"
    run_and_kill(tmp, runs, 4, sleep=1.5, timeout=240)
    finished = {p.name: p.stat().st_mtime_ns for p in runs.glob("*.h5")}
    assert 4 <= len(finished) < 8
    # the README's resume after a hard kill: the command that started the run (the
    # profile reruns the incomplete jobs; the run removes the killed run's stale lock)
    assert any((tmp / ".snakemake" / "locks").iterdir()), "a hard kill leaves the lock"
    _smk(tmp)
    redone = [n for n, t in finished.items() if (runs / n).stat().st_mtime_ns != t]
    # A file written in the instant of the kill belongs to a job Snakemake had not
    # marked finished; it runs again (rerun-incomplete, workflow/profiles/default). At most the two running jobs
    # (--cores 2) can be in that state; every finished solve is kept.
    assert len(redone) <= 2, f"finished solves were redone: {redone}"
    # and it ends where an uninterrupted run ends, bit for bit (wall times aside)
    summaries = []
    for run in (tmp, done_run):
        summary = json.loads((run / "results" / "analytic" / "summary.json").read_text())
        summary.pop("timings_s")
        summaries.append(summary)
    assert summaries[0] == summaries[1]


def test_invalid_config_stops_before_any_job_naming_the_key(base_study, tmp_path):
    tmp = _setup(tmp_path / "run", _with(base_study, smc__n_particels=10))
    proc = _smk(tmp, "-n", check=False)
    assert proc.returncode != 0
    assert "smc.n_particels" in proc.stderr + proc.stdout
    assert "did you mean 'n_particles'" in proc.stderr + proc.stdout
    assert not (tmp / "results").exists()


def test_a_users_study_layered_on_the_default_study_just_works(tmp_path):
    """The README's way to run a study: the default config/config.yaml (an fsi study
    with sigma_n2 and a warm start) and the user's file on top with --configfile. A
    python model with the noise given as sigma_n must plan its jobs without a conflict
    (later layer wins; the fsi warm start does not apply to it)."""
    (tmp_path / "config").mkdir()
    shutil.copy(REPO / "config" / "config.yaml", tmp_path / "config" / "config.yaml")
    mine = {"study": "mine", "forward_model": {
        "type": "python", "python": {"function": "bayescalib.models.analytic:interface"}},
        "likelihood": {"sigma_n": 0.002},
        "design": {"active": {"n_initial": 8, "batch_size": 4, "max_solves": 16}}}
    (tmp_path / "mine.yaml").write_text(yaml.safe_dump(mine))
    proc = _smk(tmp_path, "-n", "--configfile", str(tmp_path / "mine.yaml"))
    assert "base_state" not in proc.stdout  # no warm-start solve for a python model
    assert "results/mine/runs/0.h5" in proc.stdout


def test_the_error_that_stops_a_job_is_in_the_jobs_log(base_study, tmp_path):
    """The model fails everywhere, the ground truth included: the observe job stops with
    the reason, and the reason is in that job's own log file, not only on the console."""
    fm = {**base_study["forward_model"]}
    fm["python"] = {**fm["python"], "options": {"fail_below_E": 1.0e9}}
    _setup(tmp_path, {**base_study, "forward_model": fm})
    proc = _smk(tmp_path, check=False)
    assert proc.returncode != 0
    text = (tmp_path / "results" / "analytic" / "logs" / "observe.log").read_text()
    assert "ERROR PipelineError: the forward solve at the ground truth failed" in text
    assert "Traceback" in text


def test_a_deleted_intermediate_is_rebuilt_with_everything_built_from_it(done_run, tmp_path):
    """A hole in the results (a run record, a surrogate deleted) is never "Nothing to be
    done": the next identical command rebuilds it and what depends on it, and the
    result is the same as before."""
    tmp = _copy_run(done_run, tmp_path / "copy")
    root = tmp / "results" / "analytic"
    before = json.loads((root / "summary.json").read_text())
    (root / "runs" / "3.h5").unlink()
    (root / "rkhs" / "surrogate.h5").unlink()
    counts = job_counts(tmp)
    assert counts.get("solve") == 1 and counts.get("train_surrogate") == 1, counts
    assert counts.get("summary") == 1
    _smk(tmp)
    after = json.loads((root / "summary.json").read_text())
    assert (root / "runs" / "3.h5").is_file() and (root / "rkhs" / "surrogate.h5").is_file()
    for key in ("map", "posterior_mean", "posterior_cov", "log_evidence"):
        assert after[key] == before[key], key
    assert job_counts(tmp) == {}


@pytest.mark.parametrize("damaged", [
    pytest.param("rkhs/training.h5", marks=pytest.mark.extended),
    "rkhs/particles.h5",
    "rkhs/posterior.json",  # a JSON output: the same error on every rerun before
    pytest.param("observations/observations.h5", marks=pytest.mark.extended)])
def test_a_damaged_stage_output_is_set_aside_and_rebuilt(done_run, tmp_path, damaged):
    """One rule for every stage output: the job that finds it damaged moves it aside and
    fails saying so; the same command run again rebuilds it and what depends on it, to
    the same result."""
    tmp = _copy_run(done_run, tmp_path / "copy")
    root = tmp / "results" / "analytic"
    before = json.loads((root / "summary.json").read_text())
    path = root / damaged
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    first = _smk(tmp, check=False)
    assert first.returncode != 0
    said = first.stdout + first.stderr
    assert "cannot be read" in said and "Run the same snakemake command again" in said, \
        said[-3000:]
    assert list(path.parent.glob(path.name + "*.corrupt"))
    _smk(tmp)
    after = json.loads((root / "summary.json").read_text())
    for key in ("map", "posterior_mean", "posterior_cov", "log_evidence"):
        assert after[key] == before[key], key


def test_a_damaged_summary_is_set_aside_and_written_again(done_run, tmp_path):
    """summary.json is read by no job: the run sets a damaged one aside before it makes
    its plan, saying so, and writes it again; a dry run leaves it."""
    tmp = _copy_run(done_run, tmp_path / "copy")
    path = tmp / "results" / "analytic" / "summary.json"
    before = json.loads(path.read_text())
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert job_counts(tmp) == {} and path.is_file()  # a dry run moves nothing
    run = _smk(tmp)
    said = run.stdout + run.stderr
    assert f"the study summary '{path.relative_to(tmp)}' cannot be read" in said, said[-3000:]
    assert "This run recomputes it" in said
    assert (path.parent / "summary.json.corrupt").is_file()
    after = json.loads(path.read_text())
    for key in ("map", "posterior_mean", "posterior_cov", "log_evidence"):
        assert after[key] == before[key], key


def test_the_workflow_is_lint_clean(tmp_path):
    """``snakemake --lint``: rules and functions apart (workflow/rules/common.smk), no
    hard-coded path params, a software environment for every rule."""
    _setup(tmp_path, yaml.safe_load((REPO / "tests" / "data" / "analytic_study.yaml").read_text()))
    proc = _smk(tmp_path, "--lint", check=False)
    assert "Congratulations, your workflow is in a good condition!" in proc.stdout + proc.stderr, \
        (proc.stdout + proc.stderr)[-3000:]
