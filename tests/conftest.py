"""Shared fixtures. The workflow fixtures run Snakemake on the analytic stand-in
model (tests/data/analytic_study.yaml); the finished run is shared by every
workflow test of the session and must not be modified (copy it first).

The tests run with one BLAS thread, as the workflow's jobs do (the job server and the
diagnosis job set it): the GP fits of in-process calibrations work on small matrices,
where a second OpenBLAS thread only spins against the other processes (a surrogate
search 13-125 times slower on a shared machine, docs/surrogate.md). Set before NumPy is
imported."""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import pytest
import yaml
from _gaussian import importance_sample
from _workflow_helpers import DATA, setup_study, smk


@pytest.fixture(scope="session")
def base_study():
    return yaml.safe_load((DATA / "analytic_study.yaml").read_text())


@pytest.fixture(scope="session")
def done_run(tmp_path_factory, base_study):
    """A complete run of the analytic study (8 design points, PNG figures)."""
    tmp = setup_study(tmp_path_factory.mktemp("wf"), base_study)
    smk(tmp)
    return tmp


@pytest.fixture
def weighted_gaussian():
    """Importance sample of N(MEAN, COV) of tests/_gaussian.py: (x, normalized w)."""
    return importance_sample()


def pytest_terminal_summary(terminalreporter):
    """How many cases each fuzzer generated (the fuzz modules count them in CASES): a
    report at the end of the run, not a test."""
    import sys

    for name in ("test_config_fuzz", "test_observation_fuzz"):
        cases = getattr(sys.modules.get(name), "CASES", None)
        if cases:
            terminalreporter.write_line(
                f"{name}: {sum(cases.values())} generated cases: "
                + ", ".join(f"{k} {v}" for k, v in sorted(cases.items())))
