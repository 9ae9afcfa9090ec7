"""The SLURM profile against a real single-node SLURM cluster (slurmctld, slurmd and
munged from the Debian packages, started by benchmarks/slurm_cluster.py).

Specification: the smoke study run through ``workflow/profiles/slurm`` (solves
grouped into SLURM jobs) gives the same ``summary.json`` as a local run, apart from
timings. Skipped, with the reason, where the daemons cannot run (not root, packages
not installed)."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("slurm_cluster",
                                               REPO / "benchmarks" / "slurm_cluster.py")
slurm_cluster = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(slurm_cluster)

pytestmark = [pytest.mark.extended, pytest.mark.workflow]

#: settings of this test cluster on top of the profile: no account, job states from
#: squeue (no accounting database), quick first status check
CLUSTER_ARGS = ["--slurm-no-account", "--slurm-status-command", "squeue",
                "--slurm-init-seconds-before-status-checks", "2"]


def _checkout(dest: Path) -> Path:
    ignore = shutil.ignore_patterns(".git", ".venv", "results", ".snakemake", "__pycache__",
                                    "*.egg-info")
    shutil.copytree(REPO, dest, ignore=ignore, symlinks=True)
    return dest


def _without_timings(d):
    if isinstance(d, dict):
        return {k: _without_timings(v) for k, v in d.items() if k != "timings_s"}
    if isinstance(d, list):
        return [_without_timings(x) for x in d]
    return d


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    why = slurm_cluster.missing()
    if why:
        pytest.skip(f"no SLURM cluster here: {why}")
    state = tmp_path_factory.mktemp("slurm")
    try:
        env = slurm_cluster.start(state)
    except (RuntimeError, OSError, subprocess.CalledProcessError) as exc:
        slurm_cluster.stop(state)
        pytest.skip(f"the SLURM daemons did not start here: {exc}")
    yield env
    slurm_cluster.stop(state)


def test_the_smoke_study_on_slurm_equals_the_local_run(cluster, tmp_path):
    env = {**os.environ, **cluster}
    local = _checkout(tmp_path / "local")
    run = [sys.executable, "-m", "snakemake", "--configfile", "config/smoke.yaml"]
    proc = subprocess.run([*run, "--cores", "2"], cwd=local, env=env, capture_output=True,
                          text=True, timeout=1800, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    slurm = _checkout(tmp_path / "slurm")
    proc = subprocess.run([*run, "--profile", "workflow/profiles/slurm", *CLUSTER_ARGS],
                          cwd=slurm, env=env, capture_output=True, text=True, timeout=2400,
                          check=False)
    said = proc.stdout + proc.stderr
    assert proc.returncode == 0, said[-4000:]
    # the jobs went through SLURM, the solves grouped (the SLURM job logs of jobs that
    # succeeded are deleted by the executor; Snakemake's own log keeps the record)
    log = "\n".join(p.read_text() for p in (slurm / ".snakemake" / "log").glob("*.log"))
    assert log.count("has been submitted with SLURM jobid") >= 10, log[-3000:]
    assert "Group job solves" in log and "group_solves" in log
    a = json.loads((local / "results" / "smoke" / "summary.json").read_text())
    b = json.loads((slurm / "results" / "smoke" / "summary.json").read_text())
    assert _without_timings(a) == _without_timings(b)
