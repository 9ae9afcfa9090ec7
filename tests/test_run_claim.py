"""What makes the command that started a study also resume it, and the report's
refusal of an unfinished or live study (bayescalib.execution.resume); fast checks
without a workflow run. The README's command run after real interruptions:
tests/test_resume.py (extended)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bayescalib.execution.resume import (
    asks_report,
    claim_run,
    configfile_words,
    report_note,
    report_path,
    report_refusal,
    stale_snakemake_locks,
)
from bayescalib.study import StudyBusyError


def _locks(tmp: Path) -> Path:
    """A killed run of study 'a' and a live run of study 'b' (relative paths, as
    Snakemake writes them), plus an absolute path of 'a' in a third file."""
    locks = tmp / ".snakemake" / "locks"
    locks.mkdir(parents=True)
    (locks / "0.input.lock").write_text("results/a/runs/0.h5\nresults/a/summary.json\n")
    (locks / "0.output.lock").write_text("results/a/summary.json\n")
    (locks / "1.input.lock").write_text("results/b/runs/0.h5\nresults/ab/runs/0.h5\n")
    (locks / "1.output.lock").write_text("results/b/summary.json\n")
    (locks / "2.output.lock").write_text(f"{tmp}/results/a/runs/3.h5\n")
    return locks


def _holder(code: str) -> subprocess.Popen:
    """A process that runs ``code`` (taking a lock), says 'held' and sleeps."""
    proc = subprocess.Popen([sys.executable, "-c", code + "; print('held', flush=True); "
                             "import time; time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def _claim(tmp: Path, wait: float = 15.0) -> subprocess.CompletedProcess:
    """claim_run of study 'a' in a process of its own (the run lock it takes lasts as
    long as that process): its notes as JSON on stdout, its refusal on stderr."""
    code = ("import json; from bayescalib.execution.resume import claim_run; "
            f"print(json.dumps(claim_run('results/a', 'a', orphan_wait_s={wait})))")
    return subprocess.run([sys.executable, "-c", code], cwd=tmp, capture_output=True,
                          text=True, check=False, timeout=120)


def test_a_killed_runs_lock_is_removed_and_another_studys_lock_kept(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    locks = _locks(tmp_path)
    assert [p.name for p in stale_snakemake_locks("results/a")] == [
        "0.input.lock", "0.output.lock", "2.output.lock"]
    claimed = _claim(tmp_path)
    assert claimed.returncode == 0, claimed.stderr
    notes = json.loads(claimed.stdout)
    assert sorted(p.name for p in locks.iterdir()) == ["1.input.lock", "1.output.lock"]
    assert len(notes) == 1 and "interrupted run of study 'a'" in notes[0]
    assert "run lock results/a/.run.lock was free" in notes[0]
    assert json.loads(_claim(tmp_path).stdout) == []  # nothing more to remove


def test_a_live_run_is_never_unlocked(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    locks = _locks(tmp_path)
    live = _holder(f"from bayescalib.study import hold_run_lock; "
                   f"hold_run_lock({str(tmp_path / 'results' / 'a')!r}, 'a')")
    try:
        refused = _claim(tmp_path)
        with pytest.raises(StudyBusyError, match=rf"study 'a' is already being run .*"
                                                 rf"snakemake pid {live.pid}.* do not --unlock"):
            claim_run("results/a", "a")  # in this process: the error raised
    finally:
        live.kill()
        live.wait()
    assert refused.returncode != 0 and "StudyBusyError" in refused.stderr
    assert len(list(locks.iterdir())) == 5, "a live run's lock was removed"


def test_the_jobs_of_a_killed_run_are_waited_for_then_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _locks(tmp_path)
    take = f"from bayescalib.study import hold_job_lock; hold_job_lock({'results/a'!r})"
    # a job still ending (as after a kill: its server kills it within a second)
    ending = subprocess.Popen([sys.executable, "-c", take + "; print('held', flush=True); "
                               "import time; time.sleep(1.5)"], stdout=subprocess.PIPE,
                              text=True, cwd=tmp_path)
    try:
        assert ending.stdout.readline().strip() == "held"
        t0 = time.monotonic()
        claimed = _claim(tmp_path, wait=30)
        assert claimed.returncode == 0, claimed.stderr
        assert ending.poll() is not None and time.monotonic() - t0 < 15
    finally:
        ending.kill()
        ending.wait()
    # a job that does not end: named, and its run's lock is not removed
    (tmp_path / ".snakemake" / "locks" / "0.input.lock").write_text("results/a/runs/0.h5\n")
    orphan = subprocess.Popen([sys.executable, "-c", take + "; print('held', flush=True); "
                               "import time; time.sleep(60)"], stdout=subprocess.PIPE,
                              text=True, cwd=tmp_path)
    try:
        assert orphan.stdout.readline().strip() == "held"
        other = _claim(tmp_path, wait=0.5)
    finally:
        orphan.kill()
        orphan.wait()
    assert other.returncode != 0
    assert f"still running (pid {orphan.pid})" in other.stderr, other.stderr[-2000:]
    assert (tmp_path / ".snakemake" / "locks" / "0.input.lock").exists()


@pytest.mark.parametrize("argv, words, report", [
    (["snakemake", "--cores", "2"], "", False),
    (["snakemake", "--cores", "2", "--configfile", "config/smoke.yaml"],
     "--configfile config/smoke.yaml", False),
    (["snakemake", "--configfile", "config/heterogeneous.yaml", "config/heterogeneous_fixed.yaml",
      "--cores", "2"],
     "--configfile config/heterogeneous.yaml config/heterogeneous_fixed.yaml", False),
    (["snakemake", "--configfile=config/smoke.yaml", "-n"], "--configfile config/smoke.yaml",
     False),
    (["snakemake", "--report", "results/smoke/report.html", "--configfile", "config/smoke.yaml"],
     "--configfile config/smoke.yaml", True),
    (["snakemake", "--report=results/smoke/report.html"], "", True),
])
def test_command_lines_are_read_for_the_messages(argv, words, report):
    assert configfile_words(argv) == words
    assert asks_report(argv) is report


def test_a_report_is_refused_until_the_study_has_finished(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["snakemake", "--report", "results/a/report.html", "--configfile", "config/a.yaml"]
    never = report_refusal("results/a", "a", argv)
    assert never is not None and "it has not been run" in never
    assert "snakemake --cores 2 --configfile config/a.yaml" in never
    assert "snakemake --report results/a/report.html --configfile config/a.yaml" in never
    (tmp_path / "results" / "a").mkdir(parents=True)
    unfinished = report_refusal("results/a", "a", argv)
    assert unfinished is not None and "its run has not finished" in unfinished
    assert "the same command resumes an interrupted run" in unfinished
    (tmp_path / "results" / "a" / "summary.json").write_text("{}")
    assert report_refusal("results/a", "a", argv) is None
    live = _holder("from bayescalib.study import hold_run_lock; "
                   "hold_run_lock('results/a', 'a')")
    try:
        said = report_refusal("results/a", "a", argv)
    finally:
        live.kill()
        live.wait()
    assert said is not None and f"is being run right now (snakemake pid {live.pid}" in said
    assert "Wait for the run to end" in said


@pytest.mark.parametrize("argv, path", [
    (["snakemake", "--cores", "2"], None),
    (["snakemake", "--report"], "report.html"),  # Snakemake's default: the checkout's root
    (["snakemake", "--report", "--configfile", "config/a.yaml"], "report.html"),
    (["snakemake", "--report", "results/a/report.html"], "results/a/report.html"),
    (["snakemake", "--report=results/report.html"], "results/report.html"),
])
def test_the_report_path_is_read_and_one_outside_the_study_noted(argv, path):
    assert report_path(argv) == path
    note = report_note("results/a", argv)
    if path is None or path.startswith("results/a/"):
        assert note is None
    else:
        assert note == (f"the report goes to {path}, outside results/a/: a report of another "
                        "study made at the same path replaces it; results/a/report.html keeps "
                        "one per study")
