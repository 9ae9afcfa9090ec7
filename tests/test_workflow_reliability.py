"""Reliability of the Snakemake workflow, on the analytic stand-in model.

* a run killed (SIGKILL) while training the GP and again while running the SMC
  resumes with the README's resume command, the command that started it (no
  ``--unlock``, no ``--rerun-incomplete``), redoes no forward solve and ends with the
  summary of an uninterrupted run (the kill during the solves: tests/test_workflow.py;
  the README's command verbatim after each kind of interruption: tests/test_resume.py);
* a run record damaged after the fact is set aside by the first run that reads
  it (which fails, saying so), and the next ``snakemake --cores 2`` re-solves
  that one design point and ends with the same summary;
* two studies run at the same time in one working directory do not interfere,
  a second run of a running study is refused by Snakemake's lock, and a run
  with ``--cores 1`` gives the summary of one with ``--cores 2``, bit for bit.

Summaries are compared as parsed JSON (floats are written with ``repr``, so
equal parsed values are bitwise equal) without ``timings_s``, the only
run-dependent key. The shared uninterrupted run is the ``done_run`` fixture
(tests/conftest.py).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from _workflow_helpers import REPO, SNAKEMAKE, _env, setup_study, smk

pytestmark = pytest.mark.workflow

STUDY = Path("results") / "analytic"


def results(run: Path, study: Path = STUDY) -> dict:
    """summary.json without the wall times, plus the training table's arrays."""
    summary = json.loads((run / study / "summary.json").read_text())
    timings = summary.pop("timings_s")
    assert isinstance(timings, dict)
    with h5py.File(run / study / "rkhs" / "training.h5", "r") as f:
        table = {k: f[k][...] for k in ("X", "loglik", "D", "status")}
    return {"summary": summary, "table": table}


def assert_same_results(run: Path, reference: Path, study: Path = STUDY) -> None:
    a, b = results(run, study), results(reference)
    assert a["summary"] == b["summary"]
    for k, v in b["table"].items():
        np.testing.assert_array_equal(a["table"][k], v, err_msg=k)


def start(tmp: Path, *args: str, log: str = "snakemake.out") -> subprocess.Popen:
    """Start snakemake in its own process group (so that it can be killed as a whole)."""
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "--directory", str(tmp), *args]
    out = open(tmp / log, "w")  # noqa: SIM115 - closed with the process
    return subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                            env=_env(tmp))


def wait_for(path: Path, proc: subprocess.Popen | None = None, timeout: float = 300.0) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"snakemake ended (rc {proc.returncode}) before {path} appeared")
        if time.monotonic() > end:
            raise AssertionError(f"{path} did not appear within {timeout} s")
        time.sleep(0.05)


def kill(proc: subprocess.Popen) -> None:
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def mtimes(folder: Path, pattern: str) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in folder.glob(pattern)}


def job_stats(text: str) -> dict[str, int]:
    """Jobs per rule from the 'Job stats' table snakemake prints before running."""
    if "Job stats:" not in text:
        return {}
    counts: dict[str, int] = {}
    for line in text.split("Job stats:", 1)[1].splitlines()[3:]:
        parts = line.split()
        if len(parts) != 2 or not parts[1].isdigit():
            if counts:
                break
            continue
        counts[parts[0]] = int(parts[1])
    counts.pop("total", None)
    return counts


# ------------------------------------------------------------------ kill and resume
# extended suite (pytest -m extended, run by .ci/run): a longer variant of a check the
# default suite makes; kept out of the default suite for its time
@pytest.mark.extended
def test_killed_during_gp_training_and_smc_resumes_to_the_same_summary(base_study, tmp_path):
    # enough particles that the SMC job lasts seconds (in the warm job server the study's
    # 200 particles finish before a kill can land); the reference is the same study run
    # without interruption
    study = {**base_study, "smc": {**base_study["smc"], "n_particles": 40000, "n_rej": 10}}
    reference = setup_study(tmp_path / "reference", study)
    smk(reference)
    tmp = setup_study(tmp_path / "run", study)
    root = tmp / STUDY
    # 1. kill as soon as the GP training job has started (its log file appears)
    proc = start(tmp, "--cores", "2")
    wait_for(root / "logs" / "rkhs" / "train_surrogate.log", proc)
    kill(proc)
    assert not (root / "rkhs" / "surrogate.h5").exists(), "the kill came too late"
    runs = mtimes(root / "runs", "*.h5")
    discs = mtimes(root / "discrepancy" / "rkhs", "*.json")
    assert len(runs) == 8 and len(discs) == 8
    assert list((tmp / ".snakemake" / "locks").iterdir()), "a hard kill leaves the lock"

    # 2. resume as the README says (the same command); kill again as soon as the SMC job
    # has started
    proc = start(tmp, "--cores", "2", log="resume1.out")
    wait_for(root / "logs" / "rkhs" / "smc.log", proc)
    kill(proc)
    assert (root / "rkhs" / "surrogate.h5").is_file()
    assert not (root / "rkhs" / "particles.h5").exists(), "the kill came too late"
    stats = job_stats((tmp / "resume1.out").read_text())
    assert stats.get("train_surrogate") == 1 and "solve" not in stats, stats

    # 3. resume to the end: no solve, no discrepancy redone; the uninterrupted summary
    proc = smk(tmp)
    stats = job_stats(proc.stdout + proc.stderr)
    assert stats.get("smc") == 1 and "solve" not in stats and "train_surrogate" not in stats, \
        stats
    assert mtimes(root / "runs", "*.h5") == runs, "finished solves were redone"
    assert mtimes(root / "discrepancy" / "rkhs", "*.json") == discs
    assert_same_results(tmp, reference)


# ------------------------------------------------------------------ corrupt run record
# extended suite (pytest -m extended, run by .ci/run): a longer variant of a check the
# default suite makes; kept out of the default suite for its time
@pytest.mark.extended
def test_damaged_run_record_is_set_aside_and_resolved_on_the_next_run(done_run, tmp_path):
    tmp = tmp_path / "run"
    shutil.copytree(done_run, tmp, symlinks=True)
    runs = tmp / STUDY / "runs"
    before = mtimes(runs, "*.h5")
    data = (runs / "3.h5").read_bytes()
    (runs / "3.h5").write_bytes(data[: len(data) // 2])  # e.g. a half-copied results folder

    first = smk(tmp, check=False)
    out = first.stdout + first.stderr
    assert first.returncode != 0, "a truncated run record was used"
    assert "runs/3.h5' is corrupt or truncated" in out
    assert "Run the same snakemake command again" in out
    assert (runs / "3.h5.corrupt").is_file() and not (runs / "3.h5").exists()

    second = smk(tmp)  # the same command again
    stats = job_stats(second.stdout + second.stderr)
    assert stats.get("solve") == 1 and stats.get("discrepancy") == 1, stats
    after = mtimes(runs, "*.h5")
    assert {n for n in before if after[n] != before[n]} == {"3.h5"}
    assert_same_results(tmp, done_run)


# ------------------------------------------------------------------ concurrency
@pytest.fixture(scope="module")
def concurrent_runs(tmp_path_factory, base_study):
    """Study A (the analytic study, --cores 1) and study B (another name and design
    seed, --cores 1) started in the same working directory, one after the other, plus
    a second run of A attempted while A runs."""
    tmp = setup_study(tmp_path_factory.mktemp("concurrent"), base_study)
    other = {**json.loads(json.dumps(base_study)), "study": "other",
             "design": {**base_study["design"], "seed": 7}}
    (tmp / "config" / "other.yaml").write_text(yaml.safe_dump(other))
    a = start(tmp, "--cores", "1", log="a.out")
    try:
        wait_for(tmp / STUDY / "logs" / "ground_truth.log", a)
        b = start(tmp, "--cores", "1", "--configfile", str(tmp / "config" / "other.yaml"),
                  log="b.out")
        try:
            wait_for(tmp / "results" / "other" / "logs" / "ground_truth.log", b)
            # pause A's scheduler (its jobs in flight finish; no new one starts) so that
            # A is certainly still running while the second run is tried, however slow
            # the machine; its locks stay held
            os.kill(a.pid, signal.SIGSTOP)
            try:
                again = smk(tmp, check=False, timeout=120)
                unlock = smk(tmp, "--unlock", check=False, timeout=120)
                dry = smk(tmp, "-n", check=False, timeout=120)
                # any snakemake run that ends here (B, or the refused one) deletes
                # .snakemake/locks as a whole, A's lock included: try again after that,
                # with --rerun-incomplete, as Snakemake advises when it sees A's running
                # jobs as incomplete files
                shutil.rmtree(tmp / ".snakemake" / "locks", ignore_errors=True)
                after_unlock = smk(tmp, "--rerun-incomplete", check=False, timeout=120)
                still_running = a.poll() is None
            finally:
                os.kill(a.pid, signal.SIGCONT)
            rc_a, rc_b = a.wait(timeout=600), b.wait(timeout=600)
        finally:
            if b.poll() is None:
                kill(b)
    finally:
        if a.poll() is None:
            kill(a)
    return {"dir": tmp, "rc": (rc_a, rc_b), "again": again, "after_unlock": after_unlock,
            "unlock": unlock, "dry": dry, "a_running": still_running}


# extended suite (pytest -m extended, run by .ci/run): a longer variant of a check the
# default suite makes; kept out of the default suite for its time
@pytest.mark.extended
def test_a_second_run_of_a_running_study_is_refused(concurrent_runs):
    assert concurrent_runs["a_running"], "study A finished before the second run was tried"
    again = concurrent_runs["again"]
    assert again.returncode != 0, "a second run of a running study was let in"
    # the study's own lock answers first, before Snakemake's lock or incomplete-files
    # checks can advise --unlock or --rerun-incomplete over a live run
    said = again.stdout + again.stderr
    assert "study 'analytic' is already being run in this directory" in said, said[-2000:]
    assert "pid" in said and "Directory cannot be locked" not in said
    # unlocking a live run is refused too; a dry run (it only looks) is not
    unlock = concurrent_runs["unlock"]
    assert unlock.returncode != 0
    assert "already being run" in unlock.stdout + unlock.stderr
    assert "already being run" not in concurrent_runs["dry"].stderr
    # and still refused once Snakemake's lock folder is gone: the study's own run lock
    again = concurrent_runs["after_unlock"]
    assert again.returncode != 0, "a second run of a running study was let in"
    assert "study 'analytic' is already being run in this directory" in \
        again.stdout + again.stderr


# extended suite (pytest -m extended, run by .ci/run): a longer variant of a check the
# default suite makes; kept out of the default suite for its time
@pytest.mark.extended
def test_two_studies_in_one_directory_do_not_interfere(concurrent_runs, done_run):
    tmp = concurrent_runs["dir"]
    assert concurrent_runs["rc"] == (0, 0), (
        (tmp / "a.out").read_text()[-3000:] + (tmp / "b.out").read_text()[-3000:])
    # each study writes under its own results/<study>/ only
    a = json.loads((tmp / STUDY / "summary.json").read_text())
    b = json.loads((tmp / "results" / "other" / "summary.json").read_text())
    assert a["study"] == "analytic" and b["study"] == "other"
    for files in b["figures"].values():
        assert all(f.startswith("results/other/") for f in files)
    assert a["map"] != b["map"]  # another design: other numbers
    # study A, run next to B, equals the shared run made alone (and with --cores 2)
    assert_same_results(tmp, done_run)


# extended suite (pytest -m extended, run by .ci/run): a longer variant of a check the
# default suite makes; kept out of the default suite for its time
@pytest.mark.extended
def test_cores_1_and_cores_2_give_bitwise_equal_summaries(concurrent_runs, done_run):
    """done_run ran with --cores 2, study A of concurrent_runs with --cores 1."""
    assert concurrent_runs["rc"][0] == 0
    assert "Provided cores: 1" in (concurrent_runs["dir"] / "a.out").read_text()
    a, ref = results(concurrent_runs["dir"]), results(done_run)
    assert json.dumps(a["summary"], sort_keys=True) == json.dumps(ref["summary"], sort_keys=True)
    for k, v in ref["table"].items():
        assert a["table"][k].tobytes() == v.tobytes(), k


def test_a_resume_waits_for_the_orphaned_jobs_of_a_killed_run(done_run, tmp_path):
    """Snakemake killed hard leaves its running jobs behind. A resume started beside
    them would redo their work unguarded; it is refused, naming them, until they end."""
    import subprocess
    import sys

    tmp = tmp_path / "copy"
    shutil.copytree(done_run, tmp, symlinks=True)
    log = tmp / STUDY / "logs" / "solve" / "3.log"
    orphan = subprocess.Popen(
        [sys.executable, "-c", ("from bayescalib.stages.logs import setup_logging; "
         f"setup_logging({str(log)!r}); print('running', flush=True); "
         "import time; time.sleep(120)")], stdout=subprocess.PIPE, text=True)
    try:
        assert orphan.stdout.readline().strip() == "running"
        refused = smk(tmp, check=False, timeout=120)
        said = refused.stdout + refused.stderr
        assert refused.returncode != 0
        assert f"still running (pid {orphan.pid})" in said, said[-2000:]
    finally:
        orphan.kill()
        orphan.wait()
    assert smk(tmp, timeout=300).returncode == 0


# extended suite: the whole analytic study once more, every job in its own interpreter
@pytest.mark.extended
def test_jobs_in_fresh_interpreters_give_the_servers_summary_bitwise(base_study, done_run,
                                                                      tmp_path):
    """BAYESCALIB_JOBSERVER=off runs every job (solves, discrepancies, training tables,
    GP, SMC, acquisition, figures) in its own interpreter, the path without the warm
    servers: summary.json and the training table are bitwise those of done_run, whose
    jobs went through the point and round servers. And the results of either path are
    the other's cache: a dry run of the server path on them has nothing to do."""
    tmp = setup_study(tmp_path / "fresh", base_study)
    env = {**_env(tmp), "BAYESCALIB_JOBSERVER": "off"}
    proc = subprocess.run([*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "--directory", str(tmp),
                           "--cores", "2"], check=False, capture_output=True, text=True,
                          env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert not (tmp / STUDY / "logs" / "jobserver.log").exists()
    a, ref = results(tmp), results(done_run)
    assert json.dumps(a["summary"], sort_keys=True) == json.dumps(ref["summary"], sort_keys=True)
    for k, v in ref["table"].items():
        assert a["table"][k].tobytes() == v.tobytes(), k
    dry = smk(tmp, "-n")
    assert "Nothing to be done" in dry.stdout + dry.stderr, (dry.stdout + dry.stderr)[-3000:]
